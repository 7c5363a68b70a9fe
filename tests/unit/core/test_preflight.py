"""Preflight (federation/core/preflight.py): who is missing what before a start."""

from __future__ import annotations

from typing import Any

from federation.core.preflight import blocking, preflight

LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"


def status(agent: str, **over: Any) -> dict[str, Any]:
    ready = {
        "platform": True,
        "platform_detail": "",
        "recording": True,
        "recording_to": "runs",
        "reference_locked": True,
        "reference_bound": 0.0002,
    }
    ready |= over.pop("ready", {})
    line = {"agent": agent, "reference": LEADER, "mode": "waiting", "t_sim": 12.0, "ready": ready}
    return line | over


def test_all_ready() -> None:
    rows = preflight(
        [LEADER, FOLLOWER], {a: status(a) for a in (LEADER, FOLLOWER)}, {LEADER: 0.2, FOLLOWER: 0.5}
    )
    assert all(r.ok for r in rows) and not blocking(rows)
    assert rows[0].checks["synced"].detail == "reference"


def test_an_absent_participant_fails_every_check() -> None:
    rows = preflight([LEADER, FOLLOWER], {LEADER: status(LEADER)}, {LEADER: 0.2})
    (row,) = blocking(rows)
    assert row.agent == FOLLOWER and all(not c.ok for c in row.checks.values())
    assert row.missing[0] == "present: absent"


def test_each_failure_says_why() -> None:
    statuses = {
        LEADER: status(
            LEADER, mode="aborted", ready={"platform": False, "platform_detail": "held (aborted)"}
        ),
        FOLLOWER: status(
            FOLLOWER, ready={"reference_bound": 0.0123, "recording": False, "recording_to": None}
        ),
    }
    rows = {
        r.agent: r for r in preflight([LEADER, FOLLOWER], statuses, {LEADER: 5.0, FOLLOWER: 0.1})
    }
    assert rows[LEADER].missing == [
        "present: last status 5.0 s ago",
        "waiting: mode aborted",
        "platform: held (aborted)",
    ]
    assert rows[FOLLOWER].missing == ["synced: bound 12.30 ms > 10 ms", "recording: not recording"]


def test_not_locked_or_not_synchronized() -> None:
    unlocked = status(FOLLOWER, ready={"reference_locked": False})
    unsynced = status(FOLLOWER, t_sim=None)
    assert preflight([FOLLOWER], {FOLLOWER: unlocked}, {FOLLOWER: 0})[0].missing == [
        "synced: not locked"
    ]
    assert preflight([FOLLOWER], {FOLLOWER: unsynced}, {FOLLOWER: 0})[0].missing == [
        "synced: no reference time yet"
    ]


def test_done_is_ready_for_the_next_run_and_others_do_not_block() -> None:
    statuses = {
        LEADER: status(LEADER, mode="done"),
        "lab3/ghost": status("lab3/ghost", mode="running"),
    }
    rows = preflight([LEADER], statuses, {LEADER: 0.1, "lab3/ghost": 0.1})
    assert [r.agent for r in rows] == [LEADER, "lab3/ghost"]
    assert rows[0].ok and not rows[1].ok and not rows[1].participant
    assert blocking(rows) == []


def test_a_peer_alive_but_silent_fails_preflight_and_is_named() -> None:
    peers = {
        LEADER: {"alive": True, "silent": 2.34, "samples": 3},
        "lund/ada": {"alive": True, "silent": None, "samples": 9},
    }
    rows = preflight([FOLLOWER], {FOLLOWER: status(FOLLOWER, peers=peers)}, {FOLLOWER: 0.1})
    (row,) = blocking(rows)
    assert row.missing == [f"peers: alive but silent: {LEADER} 2.3 s"]


def test_peers_that_answer_pass_and_odd_peer_entries_are_not_alarms() -> None:
    peers: dict[str, Any] = {
        LEADER: {"alive": True, "silent": None},
        "lund/ada": "not a mapping",
        "lund/bea": {"silent": True},  # not a number of seconds
    }
    for line in (status(FOLLOWER, peers=peers), status(FOLLOWER), status(FOLLOWER, peers=[])):
        (row,) = preflight([FOLLOWER], {FOLLOWER: line}, {FOLLOWER: 0.1})
        assert row.ok and row.checks["peers"].detail == "none silent"


def test_a_participant_counting_time_on_another_clock_than_the_references_is_not_synced() -> None:
    # An SDK or ROS 2 agent is its own reference by default: it passed, and started
    # when its own clock reached an instant given on the leader's.
    own = status("lab3/sdk", reference="lab3/sdk")
    statuses = {LEADER: status(LEADER), FOLLOWER: status(FOLLOWER), "lab3/sdk": own}
    ages = dict.fromkeys(statuses, 0.1)
    rows = {r.agent: r for r in preflight(statuses, statuses, ages, reference=LEADER)}
    assert rows[LEADER].ok and rows[FOLLOWER].ok
    assert rows["lab3/sdk"].missing == [
        "synced: on lab3/sdk's clock, not the reference kiruna/knatte's"
    ]
    assert all(r.ok for r in preflight(statuses, statuses, ages))  # no reference: as before

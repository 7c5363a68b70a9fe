"""Rejoining a run under way (federation/core/rejoin.py): every row of its table, on
simulated reference time."""

from __future__ import annotations

import dataclasses

import pytest

from federation.core.rejoin import (
    AGREE,
    CHECKS,
    FRESH,
    MIN_LEFT,
    Announcement,
    Situation,
    announcement,
    decide,
    latest,
)

LEADER = Announcement(
    agent="kiruna/knatte", run_id="r1", mode="running", reference="kiruna/knatte",
    experiment="demo", t_sim=105.0, start_at=100.0, frozen_total=0.0, duration=20.0,
)  # fmt: skip
WAITING = Situation(
    me="rome/fnatte", reference="kiruna/knatte", experiment="demo", mode="waiting",
    policy="auto", admitted=False, now=106.0, seen=(LEADER,),
)  # fmt: skip


def test_a_waiting_agent_joins_at_the_present_run_time() -> None:
    d = decide(WAITING)
    assert d.join and d.run == LEADER
    assert d.run_time == pytest.approx(6.0)


def test_time_spent_frozen_is_not_run_time() -> None:
    seen = (dataclasses.replace(LEADER, frozen_total=2.5),)
    d = decide(dataclasses.replace(WAITING, seen=seen))
    assert d.join and d.run_time == pytest.approx(3.5)


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"policy": "never"}, "rejoin = never"),
        ({"uncapturable": "a formation's position reference"}, "a formation's position"),
        ({"mode": "done"}, "done: only a waiting agent rejoins"),
        ({"mode": "running"}, "running: only a waiting agent rejoins"),
        ({"now": None}, "not synchronized"),
        ({"unready": "reference clock not locked"}, "preflight: reference clock not locked"),
        ({"seen": ()}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, mode="frozen"),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, armed=True),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, agent="rome/fnatte"),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, reference="x/y"),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, experiment="other"),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, t_sim=106.0 - FRESH - 0.1),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, start_at=None),)}, "no run under way"),
        ({"seen": (dataclasses.replace(LEADER, duration=None),)}, "no run under way"),
        (
            {"seen": (LEADER, dataclasses.replace(LEADER, agent="a/b", run_id="r2"))},
            "disagree on the run",
        ),
        (
            {"seen": (LEADER, dataclasses.replace(LEADER, agent="a/b", start_at=100 + 2 * AGREE))},
            "disagree on its clock",
        ),
        (
            {
                "now": 100.0 + 20.0 - MIN_LEFT + 0.1,
                "seen": (dataclasses.replace(LEADER, t_sim=100.0 + 20.0 - MIN_LEFT),),
            },
            "too near its end",
        ),
        ({"policy": "operator"}, "waiting for an operator's admit (fedlab ctl admit rome/fnatte)"),
    ],
)
def test_each_rule_refuses(change: dict[str, object], why: str) -> None:
    d = decide(dataclasses.replace(WAITING, **change))  # type: ignore[arg-type]
    assert not d.join and why in d.why
    admit = why.startswith("waiting for an operator")
    assert d.waiting_admit == admit
    assert d.run == (LEADER if admit else None)


def test_an_admitted_operator_policy_joins() -> None:
    assert decide(dataclasses.replace(WAITING, policy="operator", admitted=True)).join


def test_an_admit_does_not_override_never() -> None:
    assert not decide(dataclasses.replace(WAITING, policy="never", admitted=True)).join


def test_announcements_within_agree_of_each_other_join() -> None:
    other = dataclasses.replace(LEADER, agent="a/b", start_at=100 + AGREE / 2)
    assert decide(dataclasses.replace(WAITING, seen=(LEADER, other))).join


def test_stale_announcements_beside_a_fresh_one_do_not_count() -> None:
    old = dataclasses.replace(LEADER, agent="a/b", run_id="r0", t_sim=50.0)
    assert decide(dataclasses.replace(WAITING, seen=(LEADER, old))).join


def test_the_table_names_every_rule_once() -> None:
    names = [name for name, _ in CHECKS]
    assert len(names) == len(set(names)) == 9


def test_the_first_refusal_answers() -> None:
    d = decide(dataclasses.replace(WAITING, policy="never", mode="done", now=None))
    assert d.why == "rejoin = never"


def test_announcement_from_a_status() -> None:
    status = {
        "run_id": "r1", "mode": "running", "reference": "kiruna/knatte", "experiment": "demo",
        "t_sim": 105.0, "start_at": 100.0, "frozen_total": 1.0, "duration": 20, "armed": None,
    }  # fmt: skip
    a = announcement("kiruna/knatte", status)
    assert a == dataclasses.replace(LEADER, frozen_total=1.0)
    assert announcement("x/y", {"mode": "waiting"}) is None
    assert announcement("x/y", {**status, "armed": {"event": "freeze", "at": 1.0}}).armed  # type: ignore[union-attr]


def test_latest_keeps_each_agents_newest() -> None:
    old = dataclasses.replace(LEADER, t_sim=90.0, run_id="r0")
    assert latest([LEADER, old]) == (LEADER,)
    assert latest([old, LEADER]) == (LEADER,)

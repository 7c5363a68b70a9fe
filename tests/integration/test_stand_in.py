"""A stand-in for a lost leader, with real processes over two routers and the link
emulator (40 ms one way): the leader (kiruna/knatte), its follower (rome/pinocchio)
and the experiment's stand-in (rome/twin, a twin of knatte's preset). The leader is
killed (SIGKILL) mid-run; the stand-in takes the role over and flies; the follower
follows it without a step in its reference beyond its platform's limits and flies the
run to its end. An outside subscriber captures every role message and status: at no
instant do two agents claim the role. The leader started again comes back deposed and
held until ``fedlab ctl handback``, after which it holds the role and the twin none."""

from __future__ import annotations

import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import pytest
from lifecycle import fedlab, runs_dir, write_experiment
from loopback import FOLLOWER, LEADER, Agent, LabPair, Labs, Tap

from federation.core import keys
from federation.core.angles import wrap_angle
from federation.runtime.agent.rejoining import limits_of
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration

TWIN = "rome/twin"
RUN = 8.0  # s of run time: the twin flies over 3 s of it after the switch
KILL_AT = 2.5  # s of run time at which the leader is killed (1.5 s into the maneuver)
AFTER = 1.5  # s of the leader's silence before the stand-in claims
LOCKED = 25.0  # s: three agents start on shared cores, then their estimates lock


def _experiment(path: Path) -> Path:
    stand_in = f'stand_in = {{ agent = "{TWIN}", preset = "knatte", after = {AFTER} }}\n'
    return write_experiment(path, RUN, name="standin", more=stand_in)


def _agents(labs: Labs, pair: LabPair, experiment: Path) -> dict[str, Agent]:
    """The three agents, the follower recording to one file."""
    at = {LEADER: pair.kiruna, FOLLOWER: pair.rome, TWIN: pair.rome}
    runs = {who: ("--runs-dir", str(runs_dir(labs, who))) for who in (LEADER, TWIN)}
    return {
        who: labs.agent(
            who,
            at[who],
            "--experiment",
            str(experiment),
            "--sync-window",
            "1",
            *runs.get(who, ()),
            record=who == FOLLOWER,
        )
        for who in (LEADER, FOLLOWER, TWIN)
    }


def _start(experiment: Path, endpoint: str) -> None:
    """``fedlab ctl start`` of the run: its preflight finds every participant ready."""
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "standin",
        "-e", endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr


def _claims(tap: Tap[tuple[float, dict[str, Any]]]) -> list[tuple[float, dict[str, Any]]]:
    """Every claim captured (role messages and statuses' ``claim``), with its receipt."""
    out = []
    for arrived, data in tap.received():
        claim = data.get("claim") if "claim" in data or "mode" in data else data
        if isinstance(claim, dict) and "holding" in claim:
            out.append((arrived, claim))
    return out


def _never_two(
    claims: list[tuple[float, dict[str, Any]]], on_one_time_base: set[str]
) -> dict[str, list[float]]:
    """Each agent's holding span per epoch (``AGENT#EPOCH``: its first ``at`` to its last
    ``until``, or ``at`` when open; reference time), judged never to overlap another's
    among ``on_one_time_base`` (a restarted reference counts its time afresh)."""
    held: dict[str, list[tuple[float, float]]] = {}
    for _, c in claims:
        if c["holding"]:
            end = c["until"] if c["until"] is not None else c["at"]
            held.setdefault(f"{c['agent']}#{c['epoch']}", []).append((c["at"], max(end, c["at"])))
    spans = {a: [min(s for s, _ in v), max(e for _, e in v)] for a, v in held.items()}
    names = sorted(a for a in spans if a in on_one_time_base)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            (a0, a1), (b0, b1) = spans[a], spans[b]
            assert a1 < b0 or b1 < a0, f"{a} held over {spans[a]}, {b} over {spans[b]}"
    return spans


def test_the_stand_in_takes_over_a_killed_leader_and_the_follower_finishes(
    labs: Labs, tmp_path: Path
) -> None:
    pair = labs.pair(link=["--delay-ms", "40"])
    experiment = _experiment(tmp_path / "exp.toml")
    fed = keys.DEFAULT_FEDERATION
    decode = lambda raw: (time.monotonic(), json.loads(raw))  # noqa: E731
    agents = _agents(labs, pair, experiment)
    leader, follower, twin = agents[LEADER], agents[FOLLOWER], agents[TWIN]
    twin.wait_status(LOCKED)  # its router is up: the outside subscriber dials it
    roles = Tap(pair.rome.endpoint, keys.all_of(fed, "role"), decode)
    statuses = Tap(pair.rome.endpoint, keys.all_of(fed, "status"), decode)
    try:
        # Before any run: the stand-in acknowledges the leader, who holds; the follower
        # follows it (no role hold), its estimate locked.
        follower.until(
            lambda s: (s.get("claim") or {}).get("follows") == LEADER
            and (s.get("ready") or {}).get("reference_locked") and s["hold"] == "waiting",
            timeout=LOCKED, what="following the leader, locked, waiting",
        )  # fmt: skip
        twin.until(lambda s: (s.get("claim") or {}).get("ack"), timeout=10, what="acknowledging")
        _start(experiment, pair.kiruna.endpoint)
        twin.until(lambda s: s["mode"] == "running", timeout=10, what="the twin in the run")
        line = follower.until(
            lambda s: (s.get("run_time") or 0.0) >= KILL_AT and s["hold"] is None,
            timeout=15, what=f"flying at run time {KILL_AT} s",
        )  # fmt: skip
        leader.kill()
        killed_at = line["run_time"]

        took = twin.until(
            lambda s: (s.get("claim") or {}).get("holding"), timeout=10, what="claimed"
        )
        print(f"leader killed at run time {killed_at:.2f} s; the twin: {took['claim']['why']}")
        assert took["claim"]["epoch"] == 2
        flying = follower.until(
            lambda s: (s.get("claim") or {}).get("follows") == TWIN and s["hold"] is None,
            timeout=10, what="following the twin, released",
        )  # fmt: skip
        print(f"the follower follows {TWIN} from run time {flying['run_time']:.2f} s")
        done = follower.until(lambda s: s["mode"] == "done", timeout=RUN + 5, what="done")
        assert done["run_time"] == pytest.approx(RUN) and done["follow"] == TWIN
        twin_done = twin.until(lambda s: s["mode"] == "done", timeout=5, what="the twin done")
        assert twin_done["claim"]["holding"]

        # The leader started again: it sees epoch 2 and is deposed, held, saying how it
        # comes back; after the handback it holds epoch 3 and the twin holds nothing.
        begun = time.monotonic()
        leader.start()
        follower.stop()  # its recording closes while the leader starts
        deposed = leader.until(
            lambda s: s["host_monotonic"] > begun
            and (s.get("claim") or {}).get("why", "").startswith("deposed"),
            timeout=20, what="deposed",
        )  # fmt: skip
        assert deposed["hold"] == "role" and not deposed["claim"]["holding"]
        assert f"fedlab ctl handback {LEADER}" in deposed["claim"]["why"]
        handed, took_s = fedlab("ctl", "handback", LEADER, "-e", pair.kiruna.endpoint)
        print(handed.stdout.strip())
        assert handed.returncode == 0, handed.stdout + handed.stderr
        assert "holds the leader's role again (epoch 3" in handed.stdout
        back = leader.until(
            lambda s: (s.get("claim") or {}).get("holding"), timeout=5, what="holds again"
        )
        assert back["claim"]["epoch"] == 3
        released = twin.until(
            lambda s: not s["claim"]["holding"] and (s["claim"]["ack"] or {}).get("epoch") == 3,
            timeout=5, what="the twin released, acknowledging epoch 3",
        )  # fmt: skip
        print(f"handed back in {took_s:.2f} s: {released['claim']['why']}")
    finally:
        roles.close()
        statuses.close()

    claims = _claims(roles) + _claims(statuses)
    first, second, third = f"{LEADER}#1", f"{TWIN}#2", f"{LEADER}#3"
    spans = _never_two(claims, {first, second})
    print(f"holding spans (reference time): {spans}; {len(claims)} claims captured")
    assert set(spans) == {first, second, third}
    assert spans[first][1] < spans[second][0] < spans[second][1]
    # The restarted leader counts reference time afresh: epochs 2 and 3 are ordered as
    # the outside subscriber received them.
    received = {
        key: [t for t, c in claims if c["holding"] and f"{c['agent']}#{c['epoch']}" == key]
        for key in (second, third)
    }
    assert max(received[second]) < min(received[third])
    # Every claim the follower sent follows one agent or none, and only a holder.
    follows = {c["follows"] for _, c in claims if c["agent"] == FOLLOWER}
    assert follows <= {LEADER, TWIN, None}, follows

    # The follower's reference: no step beyond its platform's limits, the holder named.
    refs = [
        r for r in read_messages(follower.record, ["/reference"])["/reference"]
        if r["run_time"] is not None and r["mode"] == "running"
    ]  # fmt: skip
    limits = limits_of("pinocchio", None)
    holders = [r.get("holder") for r in refs]
    assert LEADER in holders and TWIN in holders
    switch = holders.index(TWIN)
    lost = max(i for i, h in enumerate(holders[:switch]) if h == LEADER)
    # From the leader's last sample to 1 s into the twin's: the switch is captured.
    window = [
        i for i in range(lost, len(refs) - 1)
        if refs[i]["host_monotonic"] < refs[switch]["host_monotonic"] + 1.0
    ]  # fmt: skip
    # While nobody holds the role the follower holds, its valves shut: the reference it
    # predicts from the leader's last pose is not flown, so its rate's steps then ask
    # nothing of the platform (the capture at the switch starts from the last of it, and
    # its steps are checked). After a 0.39 s stall of the follower's own process that
    # prediction moved 0.9 deg/s in one step, valves shut.
    held = [i for i, h in enumerate(holders) if h is None]
    assert all(refs[i]["valves_open"] == 0 for i in held)
    worst_rate = worst_accel = 0.0
    for i, (a, b) in enumerate(itertools.pairwise(refs)):
        dt = b["host_monotonic"] - a["host_monotonic"]
        if dt <= 0:
            continue
        worst_rate = max(worst_rate, abs(wrap_angle(b["heading_ref"] - a["heading_ref"])) / dt)
        if i in window and i not in held and i + 1 not in held:
            worst_accel = max(worst_accel, abs(b["rate_ref"] - a["rate_ref"]) / dt)
    print(
        f"{len(refs)} reference samples; steepest {math.degrees(worst_rate):.2f} deg/s "
        f"(limit {math.degrees(limits.max_rate):.2f}), {math.degrees(worst_accel):.2f} deg/s^2 "
        f"(limit {math.degrees(limits.max_accel):.2f}) around the switch; "
        f"holders {sorted(set(map(str, holders)))}"
    )
    # A step would be a jump over one sample: 0.05 s apart, any jump over 1.4 deg.
    assert worst_rate <= limits.max_rate * 1.05
    assert worst_accel <= limits.max_accel * 1.05
    assert all(h != LEADER for h in holders[switch:])  # never back to a dead leader

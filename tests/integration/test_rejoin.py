"""Rejoining a run under way, with real processes over two routers and the link
emulator (40 ms one way): a simulated follower killed (SIGKILL) at run time ~6 s of a
20 s run and started again rejoins on its own (its platform's default, ``auto``) within
5 s of its start, at the present run time, and flies the run to its end with the
leader, on the same run id and end instant."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from lifecycle import QUICK_LOCK, fedlab, participants, write_experiment
from loopback import FOLLOWER, LEADER, Labs

pytestmark = pytest.mark.integration

LOCKED = 25.0  # s: the agents start (slow on a busy host), then the estimate locks 2 s in
RUN = 20.0  # s of run time
KILL_AT = 6.0  # s of run time at which the follower is killed
REJOIN_WITHIN = 5.0  # s after its start


def _rejoined(line: dict[str, object]) -> bool:
    transition = line.get("transition")
    return isinstance(transition, dict) and transition.get("event") == "rejoined"


def test_a_killed_follower_started_again_rejoins_and_flies_to_the_end(
    labs: Labs, tmp_path: Path
) -> None:
    pair = labs.pair(link=["--delay-ms", "40"])
    experiment = write_experiment(tmp_path / "exp.toml", RUN)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    leader, follower = agents[LEADER], agents[FOLLOWER]
    follower.until(
        lambda s: (s.get("ready") or {}).get("reference_locked") and s["mode"] == "waiting",
        timeout=LOCKED,
        what="locked, waiting",
    )
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "rejoin",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    line = follower.until(
        lambda s: (s.get("run_time") or 0.0) >= KILL_AT, timeout=15, what=f"run time {KILL_AT} s"
    )
    follower.kill()
    killed_at = line["run_time"]
    end_at = line["start_at"] + RUN  # the run's end instant on reference time

    begun = time.monotonic()
    follower.start()
    joined = follower.until(_rejoined, timeout=REJOIN_WITHIN + 5, what="rejoined")
    rejoin_s = time.monotonic() - begun
    transition = joined["transition"]
    gap = transition["run_time"] - killed_at
    print(
        f"killed at run time {killed_at:.2f} s; rejoined {rejoin_s:.2f} s after its start, "
        f"at run time {transition['run_time']:.2f} s (gap {gap:.2f} s)"
    )
    assert rejoin_s <= REJOIN_WITHIN, rejoin_s
    assert joined["run_id"] == "rejoin" and joined["mode"] in ("running", "done")
    assert killed_at < transition["run_time"] < RUN
    assert joined["start_at"] == pytest.approx(end_at - RUN, abs=1e-6)  # the same run

    done = follower.until(lambda s: s["mode"] == "done", timeout=RUN, what="done")
    assert done["run_id"] == "rejoin" and done["run_time"] == pytest.approx(RUN)
    assert done["transition"]["event"] == "done"
    assert done["transition"]["at"] == pytest.approx(end_at, abs=1e-6)  # the others' end
    led = leader.until(lambda s: s["mode"] == "done", timeout=5, what="the leader done")
    assert led["transition"]["at"] == pytest.approx(end_at, abs=1e-6)
    assert led["hold"] == "done" and done["hold"] == "done"

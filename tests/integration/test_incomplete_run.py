"""A run's record says what happened, with real processes: a follower stopped (SIGTERM,
as an operator's Ctrl-C) at run time ~3 s of a 6 s run, started again to serve its
recording; ``fedlab collect`` and ``fedlab report`` say it reached ~3 s and did not
complete, and that the leader completed its 6 s."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lifecycle import QUICK_LOCK, as_json, fedlab, participants, write_experiment
from loopback import FOLLOWER, LEADER, Labs

pytestmark = pytest.mark.integration

LOCKED = 25.0  # s: the agents start (slow on a busy host), then the estimate locks 2 s in
RUN = 6.0  # s of run time
STOP_AT = 3.0  # s of run time at which the follower is stopped


def test_a_follower_stopped_early_is_reported_incomplete_with_the_run_time_it_reached(
    labs: Labs, tmp_path: Path
) -> None:
    pair = labs.pair()
    experiment = write_experiment(tmp_path / "exp.toml", RUN)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    agents[FOLLOWER].until(
        lambda s: (s.get("ready") or {}).get("reference_locked") and s["mode"] == "waiting",
        timeout=LOCKED,
        what="locked, waiting",
    )
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "early",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    follower = agents[FOLLOWER]
    line = follower.until(
        lambda s: (s.get("run_time") or 0.0) >= STOP_AT, timeout=15, what=f"run time {STOP_AT} s"
    )
    follower.stop()  # SIGTERM mid-run
    stopped_at = line["run_time"]
    agents[LEADER].until(lambda s: s["mode"] == "done", timeout=15, what="the leader done")
    follower.start()  # again, to serve its recording
    follower.until(lambda s: s["mode"] == "waiting", timeout=20, what="up again")

    out = tmp_path / "collected"
    done, _ = fedlab(
        "collect", "early", "--out", str(out), "--experiment", str(experiment), "--json",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    parts = as_json(done)["participants"]
    print(f"collect: {json.dumps(parts)}")
    assert parts[LEADER] == {
        "reached_s": pytest.approx(RUN), "complete": True, "ended": "done",
        "segments_s": [[0.0, pytest.approx(RUN)]], "gaps_s": [],
    }  # fmt: skip
    reached = parts[FOLLOWER]["reached_s"]
    assert parts[FOLLOWER]["complete"] is False, parts
    assert parts[FOLLOWER]["ended"] in ("aborted", "stopped early"), parts
    assert stopped_at <= reached < stopped_at + 1.0, (stopped_at, parts)

    report, _ = fedlab("report", str(out), "--out", str(out / "report"))
    assert report.returncode == 0, report.stdout + report.stderr
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert summary["run"]["participants"] == parts and summary["run"]["complete"] is False
    text = (out / "report" / "report.md").read_text()
    assert "The run completed" not in text and "**Incomplete run**" in text
    assert f"| {FOLLOWER} | {reached:.1f} | no |" in text
    print(f"{FOLLOWER}: stopped at run time {stopped_at:.2f} s, reported reached {reached:.2f} s")

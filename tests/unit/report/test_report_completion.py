"""A run's record says what happened (federation/report/completion.py, summary.py,
markdown.py, fedlab collect): per participant the run time it reached and whether its
run completed, on synthetic recordings. A follower stopped at run time 12 s of a 30 s
run is never reported complete, however far the leader flew."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from federation.cli.collect import completions
from federation.report import load_run, write_report
from federation.report.completion import summary_lines
from federation.runtime.recorder import Recorder

LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"
DURATION = 30.0


def _event(kind: str, t: float, run_time: float | None, **extra: Any) -> dict[str, Any]:
    return {
        "event": kind, "command": None, "at": 0.0, "t_exec": t, "t_sim": t,
        "host_monotonic": t, "mode": "running", "detail": "", "run_time": run_time,
    } | extra  # fmt: skip


def _record(directory: Path, agent: str, until: float, end: str | None) -> None:
    """``agent``'s recording of a run started at reference time 0: its reference rows
    to run time ``until``, then ``end`` (done, aborted) or nothing (stopped early)."""
    rec = Recorder(directory / f"{agent.replace('/', '-')}.mcap", agent)
    start = {
        "command": "start", "seq": 1, "issuer": "ctl", "run_id": "r1",
        "participants": [LEADER, FOLLOWER], "duration": DURATION,
    }  # fmt: skip
    rec.record("/control", _event("command", -1.0, None, command=start))
    rec.record("/control", _event("started", 0.0, 0.0))
    for t in np.arange(0.0, until + 1e-9, 0.1):
        rec.record(
            "/reference",
            {
                "t_exec": t, "host_monotonic": t, "t_sim": t, "run_time": t,
                "heading_ref": 0.0, "rate_ref": 0.0, "mode": "running", "valves_open": 0,
            },
        )  # fmt: skip
    if end is not None:
        rec.record("/control", _event(end, until, until))
    role = "leader" if agent == LEADER else "follower"
    rec.record(
        "/status",
        {"agent": agent, "role": role, "t_exec": until, "host_monotonic": until, "peers": {}},
    )
    rec.close()


def _run(directory: Path, follower_until: float, follower_end: str | None) -> Path:
    directory.mkdir()
    _record(directory, LEADER, DURATION, "done")
    _record(directory, FOLLOWER, follower_until, follower_end)
    (directory / "run.json").write_text(json.dumps({"duration_s": DURATION}))
    return directory


def test_a_follower_stopped_at_12_s_of_30_s_is_reported_incomplete(tmp_path: Path) -> None:
    run_dir = _run(tmp_path / "run", 12.0, None)
    summary = write_report(run_dir, tmp_path / "out")
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    parts = on_disk["run"]["participants"]
    assert parts[LEADER] == {
        "reached_s": DURATION, "complete": True, "ended": "done",
        "segments_s": [[0.0, DURATION]], "gaps_s": [],
    }  # fmt: skip
    assert parts[FOLLOWER] == {
        "reached_s": 12.0, "complete": False, "ended": "stopped early",
        "segments_s": [[0.0, 12.0]], "gaps_s": [],
    }  # fmt: skip
    assert on_disk["run"]["complete"] is False
    assert summary["run"]["participants"] == parts
    report = (tmp_path / "out" / "report.md").read_text()
    assert "The run completed" not in report and "**Incomplete run**" in report
    assert f"| {FOLLOWER} | 12.0 | no | stopped early: no end recorded" in report
    assert f"| {LEADER} | 30.0 | yes | done" in report
    assert any(
        f"{FOLLOWER} did not complete the run (stopped early at run time 12.0 s)" in n
        for n in summary["notes"]
    )


def test_every_participant_done_is_a_completed_run(tmp_path: Path) -> None:
    run_dir = _run(tmp_path / "run", DURATION, "done")
    summary = write_report(run_dir, tmp_path / "out")
    assert summary["run"]["complete"] is True
    assert all(p["complete"] for p in summary["run"]["participants"].values())
    report = (tmp_path / "out" / "report.md").read_text()
    assert "Every participant completed its 30 s of run time." in report
    assert "Incomplete run" not in report


def test_an_aborted_participant_and_one_without_a_recording_are_not_complete(
    tmp_path: Path,
) -> None:
    run_dir = _run(tmp_path / "run", 7.5, "aborted")
    meta = {"duration_s": DURATION, "agents": {"rome/geppetto": {"role": "follower"}}}
    (run_dir / "run.json").write_text(json.dumps(meta))
    parts = load_run_parts(run_dir)
    assert parts[FOLLOWER] == {
        "reached_s": 7.5, "complete": False, "ended": "aborted",
        "segments_s": [[0.0, 7.5]], "gaps_s": [],
    }  # fmt: skip
    assert parts["rome/geppetto"] == {
        "reached_s": None, "complete": False, "ended": "no recording",
        "segments_s": [], "gaps_s": [],
    }  # fmt: skip


def _segment(directory: Path, begin: float, until: float, end: str | None, segment: int) -> None:
    """The follower's ``segment``-th recording: from a start (0) or a rejoin at run time
    ``begin`` to ``until``, then ``end`` (or nothing: killed)."""
    stem = FOLLOWER.replace("/", "-") + ("" if segment == 1 else f".seg{segment}")
    rec = Recorder(directory / f"{stem}.mcap", FOLLOWER)
    kind = "started" if segment == 1 else "rejoined"
    rec.record("/control", _event(kind, 100.0 + begin, begin))
    for t in np.arange(begin, until + 1e-9, 0.1):
        rec.record(
            "/reference",
            {
                "t_exec": 100.0 + t,
                "host_monotonic": 100.0 + t,
                "t_sim": 100.0 + t,
                "run_time": t,
                "heading_ref": 0.0,
                "rate_ref": 0.0,
                "mode": "running",
                "valves_open": 0,
            },
        )
    if end is not None:
        rec.record("/control", _event(end, 100.0 + until, until))
    rec.record(
        "/status",
        {"agent": FOLLOWER, "role": "follower", "t_exec": until, "host_monotonic": until,
         "peers": {}},
    )  # fmt: skip
    rec.close()


def test_a_follower_killed_and_rejoined_is_one_participant_in_two_segments_with_its_gap(
    tmp_path: Path,
) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _record(run_dir, LEADER, DURATION, "done")
    _segment(run_dir, 0.0, 6.0, None, 1)  # killed at 6 s
    _segment(run_dir, 8.5, DURATION, "done", 2)  # rejoined at 8.5 s, flew to the end
    (run_dir / "run.json").write_text(json.dumps({"duration_s": DURATION}))
    run = load_run(run_dir)
    assert sorted(run.agents) == [LEADER, FOLLOWER]
    assert len(run.agents[FOLLOWER].segments) == 2
    assert not any("second recording" in n for n in run.notes)
    summary = write_report(run_dir, tmp_path / "out")
    parts = summary["run"]["participants"]
    assert parts[FOLLOWER] == {
        "reached_s": DURATION, "complete": False, "ended": "done",
        "segments_s": [[0.0, 6.0], [8.5, DURATION]], "gaps_s": [[6.0, 8.5]],
    }  # fmt: skip
    assert parts[LEADER]["complete"] is True and summary["run"]["complete"] is False
    report = (tmp_path / "out" / "report.md").read_text()
    assert f"| {FOLLOWER} | 30.0 | no | done: its run time reached the duration | 2 " in report
    assert "| 6.0 to 8.5 |" in report
    assert f"| {LEADER} | 30.0 | yes | done: its run time reached the duration | 1 | - |" in report
    assert any(
        f"{FOLLOWER} flew the run in 2 segments, not from 6.0 to 8.5 s of run time" in n
        for n in summary["notes"]
    )
    lines = summary_lines(parts, DURATION)
    assert f"{FOLLOWER}: reached 30.0 s of 30 s, completed in 2 segments, gap 6.0 to 8.5 s" in lines


def test_a_later_segment_alone_is_its_agents_recording(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _segment(run_dir, 8.5, 20.0, "done", 2)  # the first segment lost
    parts = load_run_parts(run_dir)
    assert parts[FOLLOWER]["segments_s"] == [[8.5, 20.0]] and parts[FOLLOWER]["gaps_s"] == []


def load_run_parts(run_dir: Path) -> dict[str, Any]:
    from federation.report.completion import participants

    return participants(load_run(run_dir))


def test_collect_states_each_participants_run_time_and_completion(tmp_path: Path) -> None:
    run_dir = _run(tmp_path / "run", 12.0, None)
    parts, duration = completions(run_dir, {LEADER, FOLLOWER, "rome/absent"})
    assert duration == pytest.approx(DURATION)
    assert summary_lines(parts, duration) == [
        f"{LEADER}: reached 30.0 s of 30 s, completed",
        "rome/absent: no run time, no recording",
        f"{FOLLOWER}: reached 12.0 s of 30 s, stopped early: no end recorded (its process "
        "stopped or was killed)",
    ]
    assert completions(tmp_path / "empty", None) == ({}, None)  # nothing collected

"""Stand-in periods in a run's record (federation/report/completion.py): a follower whose
``/reference`` rows name the holder of the leader's role (the leader, nobody, then the
stand-in) has one stand-in period, [from, to, holder]; the stand-in's own rows mark the
time it held the role; the report's notes and collect's lines say so. A recording that
names no holder has no ``stand_in_s`` at all."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from federation.report import write_report
from federation.report.completion import summary_lines
from federation.runtime.recorder import Recorder

LEADER, FOLLOWER, TWIN = "kiruna/knatte", "rome/pinocchio", "rome/twin"
DURATION = 10.0


def _event(kind: str, t: float, run_time: float | None, **extra: Any) -> dict[str, Any]:
    return {
        "event": kind, "command": None, "at": 0.0, "t_exec": t, "t_sim": t,
        "host_monotonic": t, "mode": "running", "detail": "", "run_time": run_time,
    } | extra  # fmt: skip


def _record(directory: Path, agent: str, role: str, holder: Any) -> None:
    """``agent``'s recording of a 10 s run, done; ``holder(t)`` names the holder its
    reference row at run time ``t`` came from (None: rows without one)."""
    rec = Recorder(directory / f"{agent.replace('/', '-')}.mcap", agent)
    start = {
        "command": "start", "seq": 1, "issuer": "ctl", "run_id": "r1",
        "participants": [LEADER, FOLLOWER], "duration": DURATION,
    }  # fmt: skip
    rec.record("/control", _event("command", -1.0, None, command=start))
    rec.record("/control", _event("started", 0.0, 0.0))
    for t in np.arange(0.0, DURATION + 1e-9, 0.1):
        row = {
            "t_exec": t, "host_monotonic": t, "t_sim": t, "run_time": float(t),
            "heading_ref": 0.0, "rate_ref": 0.0, "mode": "running", "valves_open": 0,
        }  # fmt: skip
        rec.record("/reference", row if holder is None else row | {"holder": holder(t)})
    rec.record("/control", _event("done", DURATION, DURATION))
    rec.record(
        "/status",
        {"agent": agent, "role": role, "t_exec": DURATION, "host_monotonic": DURATION, "peers": {}},
    )
    rec.close()


def _follower_holder(t: float) -> str | None:
    if t < 3.0:
        return LEADER
    return None if t < 5.0 else TWIN


def test_a_follower_s_stand_in_period_is_recorded_and_said(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _record(run_dir, LEADER, "leader", lambda t: LEADER if t < 3.0 else None)
    _record(run_dir, FOLLOWER, "follower", _follower_holder)
    (run_dir / "run.json").write_text(json.dumps({"duration_s": DURATION, "leader": LEADER}))
    summary = write_report(run_dir, tmp_path / "out")
    parts = summary["run"]["participants"]
    assert parts[FOLLOWER]["stand_in_s"] == [[5.0, pytest.approx(DURATION), TWIN]]
    assert parts[LEADER]["stand_in_s"] == []  # its own rows: itself, then nobody
    assert parts[FOLLOWER]["complete"] is True  # it flew every second, following a holder
    assert any(
        f"{FOLLOWER}'s reference came from the stand-in {TWIN} from 5.0 to 10.0 s" in n
        for n in summary["notes"]
    )
    lines = summary_lines(parts, DURATION)
    assert f"{FOLLOWER}: reached 10.0 s of 10 s, completed, stand-in {TWIN} 5.0 to 10.0 s" in lines


def test_the_stand_in_s_own_rows_mark_the_time_it_held_the_role(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _record(run_dir, LEADER, "leader", None)
    _record(run_dir, TWIN, "stand-in", lambda t: TWIN if 4.0 <= t <= 8.0 else None)
    (run_dir / "run.json").write_text(json.dumps({"duration_s": DURATION, "leader": LEADER}))
    summary = write_report(run_dir, tmp_path / "out")
    parts = summary["run"]["participants"]
    assert "stand_in_s" not in parts[LEADER]  # no holder named: no stand-in kept
    assert parts[TWIN]["stand_in_s"] == [[4.0, pytest.approx(8.0), TWIN]]
    assert any(f"{TWIN} held the leader's role from 4.0 to 8.0 s" in n for n in summary["notes"])

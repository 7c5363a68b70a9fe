"""``fedlab demo --scenario formation|docking`` end to end, a few seconds of run each:
lab routers, one link emulator per dialling lab, simulated platforms as real agent
processes, the report.

These smokes show what only processes over Zenoh show: the agents start, synchronize
across the emulated 40 ms link with their clocks offset, fly the scenario's guidance
on one another's poses (the chaser's relative sensor measures the target; poses on the
wire are in the common frame), and the demo writes the report, its summary and
figures from their recordings. What the guidance achieves over a whole run (docking
within the contact criteria, its phases in order, the formation's error, every
platform kept in its area) is tests/unit/agents/test_rehearsal.py's, on simulated
time, seeded as the demo is.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from federation.runtime.recorder import read_messages

pytestmark = [pytest.mark.integration, pytest.mark.scenario]

RUN = "3"  # s of run: the demo's phases after its start, not its outcome
PHASES = ["approach", "hold", "final", "contact"]  # the chaser's, in order


def _demo(out: Path, *args: str, timeout: float) -> dict[str, Any]:
    result = subprocess.run(
        [sys.executable, "-m", "federation", "demo", *args, "--out", str(out)],
        capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


def _synced_over_the_link(out: Path, agent: str, peer: str) -> None:
    """``agent`` synchronized with ``peer`` across the emulated link: exchanges
    counted, and a one-way delay no shorter than the link's 40 ms (less its jitter)."""
    view = read_messages(out / f"{agent}.mcap")["/status"][-1]["peers"][peer]
    print(f"{agent} -> {peer}: {view['samples']} exchanges, delay {view['delay'] * 1e3:.1f} ms")
    assert view["samples"] > 0 and view["delay"] >= 0.03, view


def _in_area(summary: dict[str, Any]) -> None:
    """No platform left its area, nor was held for it (the report's workspace table)."""
    workspace = summary["workspace"]
    assert all(w["violations"] == 0 and w["holds"] == 0 for w in workspace.values()), workspace


def test_docking_demo_over_40_ms(tmp_path: Path) -> None:
    out = tmp_path / "docking"
    summary = _demo(out, "--scenario", "docking", "--duration", RUN, timeout=120)
    docking = summary["docking"]
    print({k: v for k, v in docking.items() if k != "series"})
    phases = [p for _, p in docking["phases"]]
    assert phases and phases == PHASES[: len(phases)], phases  # under way, in order
    _in_area(summary)
    _synced_over_the_link(out, "rome-pinocchio", "kiruna/knatte")
    # The chaser measured the target with its emulated sensor (counted in its status).
    status = read_messages(out / "rome-pinocchio.mcap")["/status"][-1]
    assert status["counters"]["relative_given"] > 0
    for png in ("trajectories.png", "relative_range.png"):
        assert (out / png).stat().st_size > 10_000
    assert "## Docking" in (out / "report.md").read_text()


def test_formation_demo_three_labs_over_40_ms(tmp_path: Path) -> None:
    out = tmp_path / "formation"
    summary = _demo(out, "--scenario", "formation", "--duration", RUN, timeout=120)
    formation = summary["formation"]
    print({k: v for k, v in formation.items() if k != "series"})
    assert set(formation["per_platform"]) == {"kiruna/knatte", "rome/pinocchio", "lab3/generic"}
    assert formation["latency_compensation"] is True
    _in_area(summary)
    for agent in ("rome-pinocchio", "lab3-generic"):
        _synced_over_the_link(out, agent, "kiruna/knatte")
    # Poses on the wire are in the common frame: rome's platform sits at its slot.
    sent = read_messages(out / "rome-pinocchio.mcap")["/pose/sent"][-1]
    assert abs(sent["x"] - (-3.5)) < 0.9 and abs(sent["y"] - (-2.0)) < 0.9
    for png in ("trajectories.png", "formation_error.png"):
        assert (out / png).stat().st_size > 10_000

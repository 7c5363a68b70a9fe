"""`fedlab bench scenarios` in its smallest form: one seed of each, simulated time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from federation import cli
from federation.bench import scenarios

ROOT = Path(__file__).resolve().parents[3]


def test_small_run_has_every_comparison() -> None:
    result = scenarios.run(ROOT / "deploy" / "experiments", seeds=1, docking_seeds=1)
    rows = {(r["delay_s"], r["latency_compensation"]): r for r in result["formation"]}
    assert set(rows) == {(d, c) for d in scenarios.DELAYS for c in (True, False)}
    # At a relay satellite's delay, compensation is what keeps the formation (issue 14).
    slow = max(scenarios.DELAYS)
    assert rows[(slow, True)]["error_rms_m"][0] * 2 < rows[(slow, False)]["error_rms_m"][0]
    assert all(sum(r["workspace_events"]) == 0 for r in result["formation"])
    assert result["docking"]["successes"] == 1
    assert [a["amplitude_deg"] for a in result["adaptive"]] == [
        amplitude for amplitude, _ in scenarios.ADAPTIVE_MANEUVERS
    ]


def test_command_line_refuses_zero_seeds(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["bench", "scenarios", "--seeds", "0"]) == 2
    assert "--seeds" in capsys.readouterr().out


def test_committed_results_were_made_by_this_benchmark() -> None:
    committed = json.loads((ROOT / "benchmarks" / "scenarios.json").read_text())
    assert set(committed) == {"formation", "docking", "adaptive"}
    assert committed["docking"]["successes"] == committed["docking"]["seeds"] == 10

"""`fedlab bench scenarios` in its smallest form: one seed of each, simulated time."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from rehearsed import Rehearsals

from federation import cli
from federation.bench import scenarios

ROOT = Path(__file__).resolve().parents[3]
EXPERIMENTS = ROOT / "deploy" / "experiments"


# The three parts of a run, one test each (the benchmark's parts run on separate workers).
# Their runs are the session's (tests/unit/rehearsed.py): tests/unit/agents/test_rehearsal.py
# judges the same seeded formation and adaptive runs.
def test_a_formation_row_for_every_delay_with_and_without_compensation(
    rehearsals: Rehearsals, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(scenarios, "formation_run", rehearsals.formation_run)
    formation = scenarios.formation_rows(EXPERIMENTS / "formation.toml", seeds=1)
    rows = {(r["delay_s"], r["latency_compensation"]): r for r in formation}
    assert set(rows) == {(d, c) for d in scenarios.DELAYS for c in (True, False)}
    # At a relay satellite's delay, compensation is what keeps the formation (issue 14).
    slow = max(scenarios.DELAYS)
    assert rows[(slow, True)]["error_rms_m"][0] * 2 < rows[(slow, False)]["error_rms_m"][0]
    assert all(sum(r["workspace_events"]) == 0 for r in formation)


def test_a_docking_seed_succeeds() -> None:
    assert scenarios.docking_outcomes(EXPERIMENTS / "docking.toml", seeds=1)["successes"] == 1


def test_an_adaptive_row_for_every_maneuver(
    rehearsals: Rehearsals, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(scenarios, "adaptive_run", rehearsals.adaptive_run)
    assert [a["amplitude_deg"] for a in scenarios.adaptive_rows()] == [
        amplitude for amplitude, _ in scenarios.ADAPTIVE_MANEUVERS
    ]


def test_a_run_has_every_comparison(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, Any]] = []
    monkeypatch.setattr(scenarios, "formation_rows", lambda path, n: calls.append((path.name, n)))
    monkeypatch.setattr(scenarios, "docking_outcomes", lambda path, n: calls.append((path.name, n)))
    monkeypatch.setattr(scenarios, "adaptive_rows", lambda: calls.append(("adaptive", None)))
    monkeypatch.setattr(scenarios, "transparency", lambda path, n: calls.append((path.name, n)))
    result = scenarios.run(EXPERIMENTS, seeds=2, docking_seeds=5)
    assert set(result) == {"formation", "docking", "adaptive", "transparency"}
    assert calls == [
        ("formation.toml", 2),
        ("docking.toml", 5),
        ("adaptive", None),
        ("experiments", 2),
    ]


def test_command_line_refuses_zero_seeds(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["bench", "scenarios", "--seeds", "0"]) == 2
    assert "--seeds" in capsys.readouterr().out


def test_committed_results_were_made_by_this_benchmark() -> None:
    committed = json.loads((ROOT / "benchmarks" / "scenarios.json").read_text())
    assert set(committed) == {"formation", "docking", "adaptive", "transparency"}
    assert committed["docking"]["successes"] == committed["docking"]["seeds"] == 10

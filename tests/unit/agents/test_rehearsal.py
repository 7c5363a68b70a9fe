"""Scenarios rehearsed in simulated time (agents/rehearsal.py): the issue's figures.

The real-process demos (tests/integration/test_scenarios.py) fly the same guidance
over Zenoh and the link emulator; these runs are the seeded, repeatable evidence.
"""

from __future__ import annotations

import math

import pytest

from agents.rehearsal import DelayLine, adaptive_run, docking_run, formation_run
from federation.core.wire import Pose, PoseSample
from schemas.experiment import load_experiment
from schemas.scenario import AdaptiveConfig

FORMATION = load_experiment("deploy/experiments/formation.toml")
DOCKING = load_experiment("deploy/experiments/docking.toml")


def test_delay_line_delivers_in_order_after_the_delay() -> None:
    import numpy as np

    line = DelayLine(0.25, 0.0, np.random.default_rng(0))
    line.send(0.0, PoseSample(0.0, Pose(1.0)))
    line.send(0.05, PoseSample(0.05, Pose(2.0)))
    assert line.receive(0.2) is None
    got = line.receive(0.26)
    assert got is not None and got.pose.x == 1.0
    got = line.receive(0.31)
    assert got is not None and got.pose.x == 2.0


def test_formation_compensation_halves_the_error_at_250_ms() -> None:
    comp = formation_run(FORMATION, 0.25, compensate=True, seed=0)
    raw = formation_run(FORMATION, 0.25, compensate=False, seed=0)
    print(f"250 ms: compensated {comp['error_rms_m']:.4f} m, raw {raw['error_rms_m']:.4f} m")
    assert raw["error_rms_m"] >= 2.0 * comp["error_rms_m"]
    for run in (comp, raw):
        for counters in run["workspace"].values():
            assert counters == {"workspace_clamped": 0, "workspace_holds": 0}


def test_formation_at_40_ms() -> None:
    run = formation_run(FORMATION, 0.04, compensate=True, seed=0)
    assert run["error_rms_m"] < 0.03
    assert all(c["workspace_holds"] == 0 for c in run["workspace"].values())


@pytest.mark.parametrize("seed", range(10))
def test_docking_succeeds_over_40_ms(seed: int) -> None:
    outcome = docking_run(DOCKING, 0.04, seed=seed)
    s = outcome.summary()
    assert outcome.success, s
    assert s["contact_speed_mps"] <= 0.02
    assert s["lateral_error_m"] <= 0.02
    assert s["heading_error_deg"] <= 2.0
    assert [p for _, p in outcome.phases] == ["approach", "hold", "final", "contact"]
    assert outcome.counters["relative_given"] > 0
    # the Kalman velocity estimate is good enough to dock at 1 cm/s
    assert outcome.velocity_error_rms_mps < 0.002


@pytest.mark.parametrize(("amplitude", "seconds"), [(30.0, 20.0), (60.0, 30.0), (90.0, 40.0)])
def test_adaptive_follower_tracks_brisk_leaders_closer(amplitude: float, seconds: float) -> None:
    fixed = adaptive_run(amplitude, seconds, None, seed=0)
    adaptive = adaptive_run(amplitude, seconds, AdaptiveConfig(), seed=0)
    assert adaptive["scale_max"] > 1.0
    assert adaptive["heading_error_rms_deg"] < fixed["heading_error_rms_deg"]


def test_adaptive_keeps_the_presets_gains_for_the_papers_maneuver() -> None:
    run = adaptive_run(45.0, 60.0, AdaptiveConfig(), seed=0)
    assert run["scale_max"] == 1.0
    assert math.isfinite(run["heading_error_rms_deg"])

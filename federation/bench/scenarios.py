"""Formation, docking and adaptive gains rehearsed in simulated time.

The scenarios of ``deploy/experiments/`` flown in-process (:mod:`agents.rehearsal`:
the same guidance, GNC and relative sensor as the agents, a modelled link delay,
seeded), so the comparisons are exact: the same seed and the same delays with
latency compensation on and off, or with fixed and scheduled gains. The
real-process runs are ``fedlab demo --scenario formation|docking``.

- formation: RMS and max error from the slots at 40 ms and 250 ms one way, with
  and without latency compensation, over seeds;
- docking: outcome and contact figures over seeds at 40 ms;
- adaptive: a follower's heading error with fixed and scheduled gains under
  leader maneuvers of three amplitudes and speeds;
- transparency: each scenario's tracking error at 40 ms and 250 ms over the same
  scenario with no delay, same seeds, with and without latency compensation
  (:mod:`federation.bench.transparency`).
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

from agents.rehearsal import adaptive_run, docking_run, formation_run
from federation.bench.transparency import transparency
from schemas.experiment import load_experiment
from schemas.scenario import AdaptiveConfig

__all__ = [
    "ADAPTIVE_MANEUVERS",
    "DELAYS",
    "adaptive_rows",
    "docking_outcomes",
    "formation_rows",
    "run",
]

DELAYS = (0.040, 0.250)
"""s one way: the paper's Kiruna-Rome delay and a relay satellite's."""
ADAPTIVE_MANEUVERS = ((30.0, 20.0), (60.0, 30.0), (90.0, 40.0))
"""(amplitude deg, seconds out and back) of the leader's maneuvers."""


def run(experiments: Path, seeds: int = 3, docking_seeds: int = 10) -> dict[str, Any]:
    """Every comparison; ``experiments`` is the folder of formation.toml, docking.toml
    and attitude-tracking.toml. The transparency ratios take ``seeds`` seeds."""
    return {
        "formation": formation_rows(experiments / "formation.toml", seeds),
        "docking": docking_outcomes(experiments / "docking.toml", docking_seeds),
        "adaptive": adaptive_rows(),
        "transparency": transparency(experiments, seeds),
    }


def formation_rows(experiment: Path, seeds: int) -> list[dict[str, Any]]:
    """The formation's errors and area events at each delay, compensated or not."""
    formation = load_experiment(experiment)
    rows = []
    for delay in DELAYS:
        for compensate in (True, False):
            runs = [formation_run(formation, delay, compensate, seed=s) for s in range(seeds)]
            rows.append(
                {
                    "delay_s": delay,
                    "latency_compensation": compensate,
                    "error_rms_m": [r["error_rms_m"] for r in runs],
                    "error_max_m": [r["error_max_m"] for r in runs],
                    "workspace_events": [
                        sum(
                            c["workspace_holds"] + c["workspace_clamped"]
                            for c in r["workspace"].values()
                        )
                        for r in runs
                    ],
                }
            )
    return rows


def docking_outcomes(experiment: Path, seeds: int) -> dict[str, Any]:
    """The docking's outcome over ``seeds`` at the paper's delay, and its figures."""
    docking = load_experiment(experiment)
    docks = [docking_run(docking, DELAYS[0], seed=s).summary() for s in range(seeds)]
    keys = ("contact_speed_mps", "lateral_error_m", "heading_error_deg", "time_s")
    stats = {
        k: {"median": statistics.median(d[k] for d in docks), "max": max(d[k] for d in docks)}
        for k in (*keys, "chaser_velocity_error_rms_mps")
    }
    return {
        "delay_s": DELAYS[0],
        "seeds": seeds,
        "successes": sum(bool(d["success"]) for d in docks),
        "runs": docks,
        "stats": stats,
    }


def adaptive_rows() -> list[dict[str, Any]]:
    """A follower's heading error with fixed and scheduled gains, per maneuver."""
    adaptive = []
    for amplitude, seconds in ADAPTIVE_MANEUVERS:
        fixed = adaptive_run(amplitude, seconds, None)
        scheduled = adaptive_run(amplitude, seconds, AdaptiveConfig())
        adaptive.append(
            {
                "amplitude_deg": amplitude,
                "maneuver_s": seconds,
                "fixed": {
                    k: fixed[k]
                    for k in ("heading_error_rms_deg", "heading_error_max_deg", "valve_open_s")
                },
                "adaptive": {
                    k: scheduled[k]
                    for k in (
                        "heading_error_rms_deg",
                        "heading_error_max_deg",
                        "valve_open_s",
                        "scale_max",
                    )
                },
            }
        )
    return adaptive

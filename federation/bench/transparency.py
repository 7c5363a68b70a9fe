"""Distance that does not show, measured: each scenario's transparency ratio.

The paper concludes that 3900 km between the labs "did not affect the experiment
results" and shows it by eye. Here each scenario is flown in simulated time
(:mod:`agents.rehearsal`) twice with the same seeds: once with the labs apart (a
one-way delay of 40 or 250 ms, 2 ms half-normal jitter) and once with no delay (the
same link with neither delay nor jitter: a pose arrives at the next control step).
Only the link differs: the platforms' and sensors' noise is the same draw. The ratio

.. math::

    r = \\frac{e(\\tau)}{e(0)}

of the scenario's tracking error :math:`e` with the delay :math:`\\tau` to the error
with none is 1 when distance does not show, and above 1 by what it costs. Each
scenario's :math:`e` is its own headline figure (:data:`FIGURES`):

- ``attitude-tracking``: the follower's true heading against the leader's true heading
  at the same reference time, RMS from the maneuver's start to the run's end (deg);
- ``formation``: every platform's distance from its slot around the path's centre,
  RMS over the run (m);
- ``docking``: the chaser's true lateral offset from the target's docking axis, RMS
  over the final approach (m): the offset the contact criterion judges, averaged along
  the corridor rather than taken at one instant (the contact's own lateral error is
  one draw of the sensor's noise). A run that never reaches the final approach has no
  figure (None), nor a ratio.

The no-delay run is flown with the same latency compensation setting as the delayed
one, so a ratio measures the delay alone.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.rehearsal import attitude_run, docking_run, formation_run
from schemas.experiment import ExperimentConfig, load_experiment

__all__ = ["DELAYS", "FIGURES", "JITTER", "Figure", "ratio", "scenario_rows", "transparency"]

DELAYS = (0.040, 0.250)
"""s one way: the paper's Kiruna-Rome delay and a relay satellite's."""
JITTER = 0.002
"""s: the delayed link's half-normal jitter (the no-delay link has none)."""

Error = Callable[[ExperimentConfig, float, bool, int, float | None, float], float | None]
"""(experiment, delay s, compensate, seed, duration s or None, jitter s) -> error."""


@dataclass(frozen=True)
class Figure:
    """A scenario's tracking error: its experiment file, what it is, its unit, and the
    function that flies one run and returns it."""

    experiment: str
    description: str
    unit: str
    error: Error


def _attitude(
    e: ExperimentConfig, delay: float, comp: bool, seed: int, dur: float | None, jitter: float
) -> float | None:
    run = attitude_run(e, delay, comp, seed=seed, duration=dur, jitter=jitter)
    return float(run["heading_error_rms_deg"])


def _formation(
    e: ExperimentConfig, delay: float, comp: bool, seed: int, dur: float | None, jitter: float
) -> float | None:
    run = formation_run(e, delay, comp, seed=seed, duration=dur, jitter=jitter)
    return float(run["error_rms_m"])


def _docking(
    e: ExperimentConfig, delay: float, comp: bool, seed: int, dur: float | None, jitter: float
) -> float | None:
    run = docking_run(e, delay, seed=seed, duration=dur, jitter=jitter, compensate=comp)
    return None if math.isnan(run.final_lateral_rms_m) else run.final_lateral_rms_m


FIGURES: dict[str, Figure] = {
    "attitude-tracking": Figure(
        "attitude-tracking.toml",
        "follower's heading error vs the leader's, RMS from the maneuver's start",
        "deg",
        _attitude,
    ),
    "formation": Figure("formation.toml", "slot error RMS", "m", _formation),
    "docking": Figure(
        "docking.toml", "chaser's lateral offset RMS over the final approach", "m", _docking
    ),
}
"""Each scenario's tracking error, by scenario name."""


def ratio(delayed: float | None, baseline: float | None) -> float | None:
    """``delayed / baseline``; None when either has no figure or the baseline is 0."""
    if delayed is None or baseline is None or baseline == 0.0:
        return None
    return delayed / baseline


def _spread(values: Sequence[float | None]) -> dict[str, float | None]:
    got = [v for v in values if v is not None]
    if not got:
        return {"median": None, "min": None, "max": None}
    return {"median": statistics.median(got), "min": min(got), "max": max(got)}


def scenario_rows(
    name: str,
    experiment: ExperimentConfig,
    seeds: int,
    delays: Sequence[float] = DELAYS,
    compensations: Sequence[bool] = (True, False),
    duration: float | None = None,
    jitter: float = JITTER,
) -> list[dict[str, Any]]:
    """One scenario's ratios: a row per latency compensation setting and delay.

    Each row holds ``baseline`` and ``error`` (per seed, the figure with no delay and
    with ``delay_s``), ``ratio`` per seed (None where a run has no figure) and
    ``ratio_stats`` (median, min, max over the seeds that have one)."""
    figure = FIGURES[name]
    rows = []
    for compensate in compensations:
        baseline = [
            figure.error(experiment, 0.0, compensate, s, duration, 0.0) for s in range(seeds)
        ]
        for delay in delays:
            errors = [
                figure.error(experiment, delay, compensate, s, duration, jitter)
                for s in range(seeds)
            ]
            ratios = [ratio(e, b) for e, b in zip(errors, baseline, strict=True)]
            rows.append(
                {
                    "scenario": name,
                    "figure": figure.description,
                    "unit": figure.unit,
                    "delay_s": delay,
                    "jitter_s": jitter,
                    "latency_compensation": compensate,
                    "baseline": baseline,
                    "error": errors,
                    "ratio": ratios,
                    "ratio_stats": _spread(ratios),
                }
            )
    return rows


def transparency(experiments: Path, seeds: int = 3) -> list[dict[str, Any]]:
    """Every scenario's rows (:func:`scenario_rows`); ``experiments`` is the folder of
    each :class:`Figure`'s experiment file."""
    out: list[dict[str, Any]] = []
    for name, figure in FIGURES.items():
        out += scenario_rows(name, load_experiment(experiments / figure.experiment), seeds)
    return out

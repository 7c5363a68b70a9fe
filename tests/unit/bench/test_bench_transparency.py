"""The transparency ratio (federation/bench/transparency.py) on simulated time: the same
seeds with the delay and with none, so a run at no delay is its own baseline exactly and
a delay shows only through the link."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from agents import rehearsal
from agents.guidance import track_heading
from federation.bench import transparency
from federation.bench.transparency import FIGURES, ratio, scenario_rows
from federation.core.wire import PoseSample
from schemas.experiment import ExperimentConfig, load_experiment

ROOT = Path(__file__).resolve().parents[3]
EXPERIMENTS = ROOT / "deploy" / "experiments"
ATTITUDE = load_experiment(EXPERIMENTS / "attitude-tracking.toml")
FORMATION = load_experiment(EXPERIMENTS / "formation.toml")
DOCKING = load_experiment(EXPERIMENTS / "docking.toml")
SHORT_S = 30.0  # s of run: the attitude maneuver's first 20 s, the formation's ramp and turn
HALF_S = 40.0  # s of run: the attitude maneuver out to its amplitude


def test_ratio_is_none_without_a_figure_or_a_baseline() -> None:
    assert ratio(0.3, 0.2) == pytest.approx(1.5)
    assert ratio(None, 0.2) is None
    assert ratio(0.3, None) is None
    assert ratio(0.3, 0.0) is None


@pytest.mark.parametrize(
    ("name", "experiment", "duration"),
    [("attitude-tracking", ATTITUDE, SHORT_S), ("formation", FORMATION, 12.0)],
)
def test_no_delay_is_its_own_baseline_exactly(
    name: str, experiment: ExperimentConfig, duration: float
) -> None:
    rows = scenario_rows(
        name,
        experiment,
        seeds=1,
        delays=(0.0,),
        duration=duration,
        jitter=0.0,
    )
    assert len(rows) == 2  # compensation on and off
    for row in rows:
        assert row["error"] == row["baseline"]
        assert row["ratio"] == [1.0]
        assert row["ratio_stats"] == {"median": 1.0, "min": 1.0, "max": 1.0}


def test_a_delay_without_compensation_costs_tracking() -> None:
    rows = scenario_rows(
        "attitude-tracking", ATTITUDE, seeds=2, delays=(0.25,), compensations=(False,),
        duration=SHORT_S,
    )  # fmt: skip
    (row,) = rows
    assert row["latency_compensation"] is False and row["delay_s"] == 0.25
    print(f"attitude, 250 ms, no compensation: ratios {row['ratio']}")
    assert all(r is not None and r > 1.5 for r in row["ratio"])
    assert row["ratio_stats"]["min"] == min(row["ratio"])


def test_formation_delay_with_compensation_costs_less_than_without() -> None:
    on, off = (
        scenario_rows(
            "formation", FORMATION, seeds=1, delays=(0.25,), compensations=(c,), duration=SHORT_S
        )[0]["ratio"][0]
        for c in (True, False)
    )
    print(f"formation, 250 ms, {SHORT_S:g} s: ratio {on:.3f} compensated, {off:.3f} not")
    assert on is not None and off is not None
    assert on <= 1.1 < off


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("delay", transparency.DELAYS)
def test_attitude_tracking_with_compensation_does_not_show_the_distance(
    delay: float, seed: int
) -> None:
    # The claim (issue 42, part 5): with compensation, at most 1.1 at 40 and 250 ms, the
    # median and each of seeds 0-2, over the whole run as `fedlab bench scenarios` flies it
    # (each seed at most 1.1 puts their median there too). A delay and a seed a test, so
    # that parallel workers share them: each flies the seed's baseline and its delay as
    # `scenario_rows` does (a delay of all three seeds took up to 30.0 s at nice 5 beside
    # the real-process tests, ci179).
    assert transparency.DELAYS == (0.04, 0.25)
    figure = FIGURES["attitude-tracking"]
    baseline = figure.error(ATTITUDE, 0.0, True, seed, None, 0.0)
    error = figure.error(ATTITUDE, delay, True, seed, None, transparency.JITTER)
    r = ratio(error, baseline)
    print(f"attitude, {delay * 1e3:.0f} ms, seed {seed}, compensated: ratio {r}")
    assert r is not None and r <= 1.1


def test_attitude_excess_with_dead_reckoning_is_its_rate_reference(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Dead reckoning moves the received heading on by rate x age but gives the received
    # rate, one delay old and carrying the sender's gyro noise, as the rate reference,
    # which the heading controller weighs by kd / kp = 1.5 s. The follower's estimator
    # (agents.guidance.HeadingEstimator) gives a rate from the headings' trend and the
    # maneuver; swapped for dead reckoning in the same rehearsal, the ratio exceeds 1.1.
    class DeadReckoning:
        def reference(
            self, received: PoseSample, now: float, compensate: bool, *_: Any
        ) -> tuple[float, float]:
            return track_heading(received, now, compensate)

    def one() -> float | None:
        (row,) = scenario_rows(
            "attitude-tracking", ATTITUDE, seeds=1, delays=(0.25,), compensations=(True,),
            duration=HALF_S,
        )  # fmt: skip
        got: float | None = row["ratio"][0]
        return got

    estimated = one()
    monkeypatch.setattr(rehearsal, "HeadingEstimator", DeadReckoning)
    dead_reckoned = one()
    print(f"attitude, 250 ms: ratio {estimated:.3f} estimated, {dead_reckoned:.3f} dead reckoned")
    assert estimated is not None and dead_reckoned is not None
    assert estimated <= 1.1 < dead_reckoned


def test_docking_has_no_figure_before_the_final_approach() -> None:
    # 20 s of run ends in the approach: no final-approach offset to score, no ratio.
    (row,) = scenario_rows(
        "docking", DOCKING, seeds=1, delays=(0.04,), compensations=(True,), duration=20.0
    )
    assert row["baseline"] == [None] and row["ratio"] == [None]
    assert row["ratio_stats"]["median"] is None


def test_every_scenario_is_scored_from_its_experiment_file() -> None:
    assert set(FIGURES) == {"attitude-tracking", "formation", "docking"}
    for name, figure in FIGURES.items():
        assert load_experiment(EXPERIMENTS / figure.experiment).kind == name
    assert transparency.DELAYS == (0.040, 0.250)
    assert math.isclose(transparency.JITTER, 0.002)

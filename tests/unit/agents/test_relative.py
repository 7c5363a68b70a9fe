"""The emulated relative sensor (agents/relative.py), paper section 3.2."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.relative import RelativeSensor, dead_reckon, to_common
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import RelativeSensorConfig

QUIET = RelativeSensorConfig(
    range_noise=0, range_noise_per_m=0, bearing_noise_deg=0, bearing_noise_per_m_deg=0,
    heading_noise_deg=0, dropout=0, rate=10,
)  # fmt: skip


def test_dead_reckoning_moves_the_pose_on_by_its_rates() -> None:
    pose = Pose(1.0, 2.0, 0.1, 0.1, -0.2, 0.05)
    assert dead_reckon(pose, 2.0) == pytest.approx(Pose(1.2, 1.6, 0.2, 0.1, -0.2, 0.05))
    assert dead_reckon(pose, 5.0, horizon=1.0) == dead_reckon(pose, 1.0)
    assert dead_reckon(pose, -1.0) == pose


def test_noiseless_measurement_is_the_difference_of_the_poses_dead_reckoned() -> None:
    sensor = RelativeSensor(QUIET)
    own = Pose(1.0, 0.0, math.pi)  # facing -x
    other = (9.8, Pose(0.0, 0.0, 0.0, 0.05, 0.0, 0.0))  # stamped 0.2 s ago, moving +x
    m = sensor.measure(10.0, other, own)
    assert m is not None
    assert m.range == pytest.approx(0.99)  # it moved 1 cm towards us since its stamp
    assert m.bearing == pytest.approx(0.0, abs=1e-12)
    assert abs(m.heading) == pytest.approx(math.pi)
    x, y, _ = to_common(own, m)
    assert (x, y) == pytest.approx((0.01, 0.0))


def test_without_compensation_a_late_pose_is_measured_where_it_was() -> None:
    sensor = RelativeSensor(QUIET, compensate=False)
    own = Pose(1.0, 0.0, math.pi)
    other = (9.75, Pose(0.0, 0.0, 0.0, 0.05, 0.0, 0.0))  # stamped 250 ms ago, moving +x
    m = sensor.measure(10.0, other, own)
    assert m is not None and m.range == pytest.approx(1.0)  # not moved on
    assert sensor.counters[Count.RELATIVE_GIVEN] == 1
    # Past the horizon it is stale, compensated or not.
    assert sensor.measure(12.0, (10.5, other[1]), own) is None
    assert sensor.counters[Count.RELATIVE_STALE_POSE] == 1


def test_field_of_view_range_and_rate() -> None:
    sensor = RelativeSensor(QUIET.model_copy(update={"fov_deg": 60, "max_range": 2.0}))
    own = Pose()
    assert sensor.measure(0.0, (0.0, Pose(1.0, 1.0)), own) is None  # 45 deg off: out of view
    assert sensor.measure(0.05, (0.0, Pose(1.0, 0.0)), own) is None  # not due (10 Hz)
    assert sensor.measure(0.1, (0.0, Pose(3.0, 0.0)), own) is None  # beyond max range
    assert sensor.measure(0.2, (0.0, Pose(1.0, 0.1)), own) is not None
    assert sensor.measure(0.3, None, own) is None
    assert sensor.counters == {
        Count.RELATIVE_GIVEN: 1,
        Count.RELATIVE_OUT_OF_VIEW: 2,
        Count.RELATIVE_DROPPED: 0,
        Count.RELATIVE_NO_POSE: 1,
        Count.RELATIVE_STALE_POSE: 0,
    }


def test_noise_grows_with_range_and_is_seeded() -> None:
    config = RelativeSensorConfig(dropout=0, fov_deg=180, max_range=10)

    def spread(distance: float, seed: int = 0) -> tuple[float, float]:
        sensor = RelativeSensor(config.model_copy(update={"seed": seed}))
        got = [sensor.measure(k * 0.1, (k * 0.1, Pose(distance, 0.0)), Pose()) for k in range(2000)]
        r = np.array([m.range for m in got if m is not None])
        b = np.array([m.bearing for m in got if m is not None])
        return float(np.std(r)), float(np.std(b))

    near, far = spread(0.5), spread(4.0)
    assert near[0] == pytest.approx(0.002 + 0.004 * 0.5, rel=0.1)
    assert far[0] == pytest.approx(0.002 + 0.004 * 4.0, rel=0.1)
    assert far[1] == pytest.approx(math.radians(0.1 + 0.1 * 4.0), rel=0.1)
    assert spread(1.0, seed=3) == spread(1.0, seed=3)
    assert spread(1.0, seed=3) != spread(1.0, seed=4)


def test_dropouts_at_the_configured_rate() -> None:
    sensor = RelativeSensor(RelativeSensorConfig(dropout=0.2, seed=1))
    for k in range(5000):
        sensor.measure(k * 0.1, (k * 0.1, Pose(1.0, 0.0)), Pose())
    assert sensor.counters[Count.RELATIVE_DROPPED] / 5000 == pytest.approx(0.2, abs=0.02)


def test_a_shared_pose_older_or_further_ahead_than_the_horizon_gives_no_measurement() -> None:
    # From a silent target's frozen pose it measured for ever, so docking never lost it.
    sensor = RelativeSensor(QUIET)
    own = Pose(1.0, 0.0, math.pi)
    assert sensor.measure(10.0, (9.5, Pose()), own) is not None  # within the 1 s horizon
    assert sensor.measure(10.1, (8.5, Pose()), own) is None  # 1.6 s old
    assert sensor.measure(10.2, (100.0, Pose()), own) is None  # 90 s ahead
    assert sensor.counters[Count.RELATIVE_STALE_POSE] == 2

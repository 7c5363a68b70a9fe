"""IMU and vision models (agents/sensors.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.sensors import Coverage, Imu, ImuSample, Sampler, Vision, wrap_angle

N = 20_000


def imu(seed: int = 0) -> Imu:
    return Imu(100.0, 0.002, 0.005, 0.01, (0.002, -0.001), np.random.default_rng(seed))


KNATTE_AREA = Coverage(3.0, 1.7)


def vision(seed: int = 0, coverage: Coverage = KNATTE_AREA) -> Vision:
    return Vision(20.0, 0.005, 0.0087, coverage, np.random.default_rng(seed))


@pytest.mark.parametrize(
    ("angle", "wrapped"),
    [
        (0.0, 0.0),
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3 * math.pi, math.pi),
        (2 * math.pi + 0.1, 0.1),
        (-0.1, -0.1),
        (7.0, 7.0 - 2 * math.pi),
    ],
)
def test_wrap_angle(angle: float, wrapped: float) -> None:
    assert wrap_angle(angle) == pytest.approx(wrapped)


def test_imu_noise_and_bias() -> None:
    samples = np.array(_stream(imu(), N))
    gyro, ax, ay = samples[:, 0], samples[:, 1], samples[:, 2]
    assert gyro.mean() == pytest.approx(0.1 + 0.005, abs=4 * 0.002 / math.sqrt(N))
    assert ax.mean() == pytest.approx(0.02 + 0.002, abs=4 * 0.01 / math.sqrt(N))
    assert ay.mean() == pytest.approx(-0.04 - 0.001, abs=4 * 0.01 / math.sqrt(N))
    assert gyro.std() == pytest.approx(0.002, rel=0.03)
    assert ax.std() == pytest.approx(0.01, rel=0.03)
    assert ay.std() == pytest.approx(0.01, rel=0.03)
    assert abs(np.corrcoef(gyro, ax)[0, 1]) < 0.05


def _stream(sensor: Imu, n: int) -> list[ImuSample]:
    return [sensor.measure(0.1, 0.02, -0.04) for _ in range(n)]


def test_seeded_runs_repeat() -> None:
    assert _stream(imu(7), 2000) == _stream(imu(7), 2000)
    assert _stream(imu(7), 10) != _stream(imu(8), 10)
    a, b = vision(3), vision(3)
    assert [a.measure(0.1, 0.2, 0.3) for _ in range(50)] == [
        b.measure(0.1, 0.2, 0.3) for _ in range(50)
    ]


def test_vision_noise() -> None:
    v = vision()
    fixes = np.array([pose[:3] for pose in (v.measure(0.5, -0.3, 1.0) for _ in range(N)) if pose])
    assert len(fixes) == N
    assert fixes.mean(axis=0) == pytest.approx([0.5, -0.3, 1.0], abs=4 * 0.0087 / math.sqrt(N))
    assert fixes.std(axis=0) == pytest.approx([0.005, 0.005, 0.0087], rel=0.03)


def test_vision_fix_is_a_pose_with_zero_rates() -> None:
    fix = vision().measure(0.0, 0.0, 0.0)
    assert fix is not None
    assert (fix.vx, fix.vy, fix.omega) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("x", "y", "seen"),
    [
        (0.0, 0.0, True),
        (1.49, 0.84, True),
        (-1.49, -0.84, True),
        (1.51, 0.0, False),
        (0.0, 0.86, False),
        (-1.6, -0.9, False),
        (0.0, -0.86, False),
    ],
)
def test_no_fix_outside_the_camera_area(x: float, y: float, seen: bool) -> None:
    # KNATTE: 3.0 x 1.7 m centred at the origin
    assert (vision().measure(x, y, 0.0) is not None) is seen


def test_coverage_with_an_origin() -> None:
    v = vision(coverage=Coverage(2.0, 1.0, cx=1.0, cy=0.5))
    assert v.measure(1.9, 0.9, 0.0) is not None
    assert v.measure(-0.1, 0.5, 0.0) is None
    assert v.measure(1.0, -0.1, 0.0) is None


def test_vision_heading_is_wrapped() -> None:
    v = Vision(20.0, 0.0, 0.0, Coverage(3.0, 1.7), np.random.default_rng(0))
    fix = v.measure(0.0, 0.0, math.pi + 0.25)
    assert fix is not None
    assert fix.heading == pytest.approx(-math.pi + 0.25)


def test_sampler_20_hz_from_100_hz_ticks() -> None:
    s = Sampler(20.0)
    due = [k for k in range(100) if s.due(5.0 + k / 100)]
    assert due == list(range(0, 100, 5))


def test_sampler_ignores_jitter_and_skips_gaps() -> None:
    s = Sampler(10.0)
    assert s.due(0.0)
    assert not s.due(0.0999)
    assert s.due(0.1003)  # late: fires, next stays on the grid at 0.2
    assert not s.due(0.15)
    assert s.due(0.2)
    assert s.due(5.0)  # a gap: one sample, not a burst of 48
    assert not s.due(5.05)
    assert s.due(5.1)


def test_sampler_rejects_a_bad_rate() -> None:
    with pytest.raises(ValueError, match="rate"):
        Sampler(0.0)

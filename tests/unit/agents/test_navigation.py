"""IMU/vision Kalman filter (agents/navigation.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.guidance import ReferenceManeuver
from agents.navigation import NavigationFilter
from agents.sensors import Coverage, Imu, ImuSample, Vision
from federation.core.wire import Pose
from schemas.platform import PlatformConfig, load_platform

KNATTE = load_platform("knatte")
PAPER = ReferenceManeuver()  # 10 s still, 45 deg out and back in 60 s
RATE = 100.0


def make_filter(config: PlatformConfig = KNATTE) -> NavigationFilter:
    i, v, n = config.imu, config.vision, config.navigation
    return NavigationFilter(
        i.gyro_noise,
        i.accel_noise,
        v.position_noise,
        v.heading_noise,
        n.unmodelled_accel,
        n.gyro_bias_walk,
        n.accel_bias_walk,
    )


def fly_maneuver(
    config: PlatformConfig, seed: int
) -> tuple[np.ndarray, np.ndarray, NavigationFilter]:
    """The paper's maneuver as truth (kinematic, at rest at the origin): heading errors."""
    i, v = config.imu, config.vision
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2)]
    imu = Imu(i.rate, i.gyro_noise, i.gyro_bias, i.accel_noise, i.accel_bias, rngs[0])
    cam = Vision(v.rate, v.position_noise, v.heading_noise, Coverage(v.width, v.height), rngs[1])
    nav = make_filter(config)
    errors, positions = [], []
    for k in range(int(80 * RATE) + 1):
        t = k / RATE
        heading, rate = PAPER(t)
        nav.predict(t, imu.measure(rate, 0.0, 0.0))
        if cam.sampler.due(t):
            fix = cam.measure(0.0, 0.0, heading)
            assert fix is not None
            nav.correct(t, fix)
        est = nav.estimate
        errors.append(est.heading - heading)
        positions.append(math.hypot(est.x, est.y))
    return np.array(errors), np.array(positions), nav


@pytest.mark.parametrize("seed", [0, 1])
def test_heading_rms_at_most_half_the_vision_noise(seed: int) -> None:
    """Done-when 2 (filter alone): heading RMS error <= sigma_vision / 2 over the maneuver."""
    errors, positions, nav = fly_maneuver(KNATTE, seed)
    rms = float(np.sqrt(np.mean(errors**2)))
    sigma = KNATTE.vision.heading_noise
    print(
        f"\n[filter] KNATTE, paper maneuver, seed {seed}: heading RMS error "
        f"{math.degrees(rms):.3f} deg = {rms / sigma:.3f} x vision sigma "
        f"({math.degrees(sigma):.2f} deg); bound 0.5; gyro bias "
        f"{nav.gyro_bias:.5f} rad/s (true {KNATTE.imu.gyro_bias})"
    )
    assert rms <= 0.5 * sigma
    assert nav.gyro_bias == pytest.approx(KNATTE.imu.gyro_bias, abs=5e-4)
    assert positions[-1000:].max() < 0.01  # position held near the truth (0, 0)


def test_vision_alone_would_not_do() -> None:
    """The bound is not trivial: raw fixes have RMS error sigma, twice the bound."""
    v = Vision(20.0, 0.005, KNATTE.vision.heading_noise, Coverage(3, 1.7), np.random.default_rng(0))
    raw = np.array([fix.heading for fix in (v.measure(0.0, 0.0, 0.0) for _ in range(1600)) if fix])
    assert np.sqrt(np.mean(raw**2)) > 0.5 * KNATTE.vision.heading_noise


def test_noise_free_tracking_has_no_lag() -> None:
    nav = make_filter()
    worst = 0.0
    for k in range(8001):
        t = k / RATE
        heading, rate = PAPER(t)
        nav.predict(t, ImuSample(rate, 0.0, 0.0))
        if k % 5 == 0:
            nav.correct(t, Pose(0.0, 0.0, heading))
        worst = max(worst, abs(nav.estimate.heading - heading))
        assert nav.estimate.omega == pytest.approx(rate - nav.gyro_bias)
    assert worst < 1e-5


def test_gyro_alone_between_fixes() -> None:
    """Without vision the heading is the integrated gyro (trapezoid rule, exact here)."""
    nav = make_filter()
    nav.predict(0.0, ImuSample(0.1, 0.0, 0.0))
    for k in range(1, 101):
        nav.predict(k * 0.01, ImuSample(0.1 + 0.002 * k, 0.0, 0.0))  # rate ramps
    expected = 0.1 * 1.0 + 0.5 * 0.2 * 1.0  # integral of 0.1 + 0.2 t over 1 s
    assert nav.estimate.heading == pytest.approx(expected, rel=1e-9)
    assert nav.time == 1.0
    sigma_before = nav.heading_sigma
    nav.correct(1.0, Pose(0.0, 0.0, expected))
    assert nav.heading_sigma < sigma_before


def test_accelerometers_in_the_body_frame() -> None:
    """Heading 90 deg, body +x push: the velocity estimate grows along lab +y."""
    nav = NavigationFilter(0.002, 0.01, 0.005, 0.0087, initial=Pose(heading=math.pi / 2))
    a = 0.04
    nav.predict(0.0, ImuSample(0.0, a, 0.0))
    for k in range(1, 101):
        nav.predict(k * 0.01, ImuSample(0.0, a, 0.0))
    est = nav.estimate
    assert est.vy == pytest.approx(a * 1.0, rel=1e-6)
    assert est.y == pytest.approx(0.5 * a * 1.0, rel=1e-6)
    assert abs(est.vx) < 1e-12


def test_heading_stays_continuous_across_the_wrap() -> None:
    nav = make_filter()
    nav.predict(0.0, ImuSample(0.0, 0.0, 0.0))
    nav.correct(0.0, Pose(0.0, 0.0, math.pi - 0.01))
    nav.predict(0.01, ImuSample(0.0, 0.0, 0.0))
    nav.correct(0.01, Pose(0.0, 0.0, -math.pi + 0.01))  # the same attitude, 0.02 rad on
    heading = nav.estimate.heading
    assert math.pi - 0.02 < heading < math.pi + 0.02


def test_first_fix_sets_the_pose() -> None:
    nav = make_filter()
    nav.predict(3.0, ImuSample(0.0, 0.0, 0.0))
    nav.correct(3.0, Pose(1.2, -0.4, 0.5))
    est = nav.estimate
    assert (est.x, est.y, est.heading) == pytest.approx((1.2, -0.4, 0.5), abs=1e-3)


def test_time_never_goes_back() -> None:
    nav = make_filter()
    nav.predict(1.0, ImuSample(0.1, 0.0, 0.0))
    nav.predict(2.0, ImuSample(0.1, 0.0, 0.0))
    heading = nav.estimate.heading
    nav.predict(1.5, ImuSample(0.1, 0.0, 0.0))  # stale: ignored for the state
    assert nav.estimate.heading == heading
    assert nav.time == 2.0


def test_innovation_distance_is_in_sigmas_of_the_innovation_covariance() -> None:
    """What the chain's outlier gate measures: sqrt(nu' S^-1 nu), S = H P H' + R."""
    nav = make_filter()
    nav.predict(0.0, ImuSample(0.0, 0.0, 0.0))
    for k in range(1, 201):
        nav.predict(k * 0.01, ImuSample(0.0, 0.0, 0.0))
        if k % 5 == 0:
            nav.correct(k * 0.01, Pose(0.0, 0.0, math.pi - 0.001))
    kf = nav.kf
    s = kf.H @ kf.P @ kf.H.T + kf.R
    sx, spsi = math.sqrt(s[0, 0]), math.sqrt(s[2, 2])
    assert nav.innovation_distance(Pose(0.0, 0.0, math.pi - 0.001)) == pytest.approx(0, abs=0.01)
    assert nav.innovation_distance(Pose(5 * sx, 0.0, math.pi - 0.001)) == pytest.approx(5, rel=0.01)
    # Heading wrapped: -pi + 0.001 is 0.002 rad from pi - 0.001, not 2 pi.
    across = nav.innovation_distance(Pose(0.0, 0.0, -math.pi + 0.001))
    assert across == pytest.approx(0.002 / spsi, rel=0.01) and across < 1
    assert nav.innovation_distance(Pose(5.0, 0.0, 0.0)) > 500
    for bad in (Pose(math.nan, 0, 0), Pose(0, math.inf, 0), Pose(0, 0, math.nan), Pose(3e38, 0, 0)):
        assert nav.innovation_distance(bad) > 1e30 or nav.innovation_distance(bad) == math.inf
    assert nav.innovation_distance(Pose(math.nan, 0, 0)) == math.inf


def test_motion_since_is_the_predictions_alone_and_reaches_back_its_history() -> None:
    nav = NavigationFilter(0.002, 0.01, 0.005, 0.0087, history=0.5)
    turning = ImuSample(1.0, 0.0, 0.0)  # 1 rad/s, no acceleration
    for k in range(101):
        nav.predict(k * 0.01, turning)
        if k == 50:  # a fix 1.5 rad from the estimate: news, not motion
            nav.correct(0.5, Pose(0.0, 0.0, 2.0))
    assert nav.estimate.heading > 1.5
    assert nav.motion_since(0.9) == pytest.approx((0.0, 0.0, 0.1), abs=1e-3)
    assert nav.motion_since(0.905) == pytest.approx((0.0, 0.0, 0.095), abs=1e-3)  # between
    assert nav.motion_since(0.5) == pytest.approx((0.0, 0.0, 0.5), abs=1e-3)  # kept: 0.5 s
    assert nav.motion_since(0.2) is None and not nav.reaches(0.8)  # not kept: not known
    assert nav.reaches(0.5) and nav.reaches(0.0)
    assert nav.motion_since(1.0) == nav.motion_since(2.0) == (0.0, 0.0, 0.0)
    assert NavigationFilter(0.002, 0.01, 0.005, 0.0087).motion_since(0.0) is None


def test_motion_since_spans_a_step_longer_than_its_history() -> None:
    # A host stalled 0.6 s (history 0.5 s): the entry before the stall had been dropped
    # and a turn of 1 rad/s showed no motion at all over the last 0.1 s.
    nav = NavigationFilter(0.002, 0.01, 0.005, 0.0087, history=0.5)
    turning = ImuSample(1.0, 0.0, 0.0)
    for t in (0.0, 0.01, 0.49, 1.09):
        nav.predict(t, turning)
    assert nav.motion_since(0.99)[2] == pytest.approx(0.1, abs=1e-6)


class _Filterpy(NavigationFilter):
    """The navigation filter with filterpy's own ``KalmanFilter.predict`` and ``update``
    in place of its arithmetic (the oracle it reimplements without importing it)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        from filterpy.kalman import KalmanFilter

        self.oracle = KalmanFilter(dim_x=8, dim_z=3, dim_u=3)

    def _sync_in(self) -> None:
        for name in ("x", "P", "F", "B", "Q", "H", "R"):
            setattr(self.oracle, name, getattr(self.kf, name).copy())

    def _predict(self, u: np.ndarray) -> None:
        self._sync_in()
        self.oracle.predict(u)
        self.kf.x, self.kf.P = self.oracle.x.copy(), self.oracle.P.copy()

    def _update(self, z: np.ndarray) -> None:
        self._sync_in()
        self.oracle.update(z)
        self.kf.x, self.kf.P = self.oracle.x.copy(), self.oracle.P.copy()


def test_the_filter_computes_what_filterpy_computes_bit_for_bit() -> None:
    # A turning, accelerating platform with noisy IMU samples at 100 Hz and late vision
    # fixes at 10 Hz: every state and covariance equal filterpy's, to the last bit.
    i, v, n = KNATTE.imu, KNATTE.vision, KNATTE.navigation
    args = (i.gyro_noise, i.accel_noise, v.position_noise, v.heading_noise,
            n.unmodelled_accel, n.gyro_bias_walk, n.accel_bias_walk)  # fmt: skip
    ours, theirs = NavigationFilter(*args), _Filterpy(*args)
    rng = np.random.default_rng(3)
    for k in range(600):  # bounded: 6 s at 100 Hz
        t = k * 0.01
        imu = ImuSample(0.2 * math.sin(t) + rng.normal(0, 0.01), rng.normal(0.01, 0.02),
                        rng.normal(0, 0.02))  # fmt: skip
        for nav in (ours, theirs):
            nav.predict(t, imu)
        if k % 10 == 5:
            fix = Pose(0.01 * t + rng.normal(0, 0.002), rng.normal(0, 0.002), 0.1 * t)
            for nav in (ours, theirs):
                nav.correct(t, fix, age=0.03)
        assert np.array_equal(ours.kf.x, theirs.kf.x), k
        assert np.array_equal(ours.kf.P, theirs.kf.P), k
    assert ours.fixes == theirs.fixes == 60

"""Guidance and the kinematic platform (agents/guidance.py, agents/kinematic.py)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import KinematicPlatform, ReferenceManeuver, track_heading
from agents.guidance import HeadingEstimator, HeadingFilter
from federation.core.angles import wrap_angle
from federation.core.wire import Pose, PoseSample

DEG45 = math.radians(45.0)
paper = ReferenceManeuver()


# --------------------------------------------------------- ReferenceManeuver


def test_defaults_are_the_papers() -> None:
    assert paper.start == 10.0
    assert paper.duration == 60.0
    assert paper.amplitude == pytest.approx(math.pi / 4)


@pytest.mark.parametrize("t", [-100.0, -1.0, 0.0, 5.0, 9.0, 9.999])
def test_still_before_10_s(t: float) -> None:
    assert paper(t) == (0.0, 0.0)


@pytest.mark.parametrize("t", [70.001, 71.0, 100.0, 600.0, 1e9])
def test_still_after_70_s(t: float) -> None:
    assert paper(t) == (0.0, 0.0)


def test_peak_45_deg_at_40_s() -> None:
    heading, rate = paper(40.0)
    assert heading == pytest.approx(DEG45, abs=1e-12)
    assert math.degrees(heading) == pytest.approx(45.0, abs=1e-9)
    assert rate == pytest.approx(0.0, abs=1e-12)


def test_peak_is_the_maximum() -> None:
    headings = [paper(10.0 + 0.05 * k)[0] for k in range(1201)]
    assert max(headings) == pytest.approx(DEG45, abs=1e-12)
    assert headings.index(max(headings)) == 600  # t = 40 s
    assert min(headings) >= 0.0


def test_endpoints_are_zero() -> None:
    for t in (10.0, 70.0):
        heading, rate = paper(t)
        assert heading == pytest.approx(0.0, abs=1e-12)
        assert rate == pytest.approx(0.0, abs=1e-12)


def test_quarter_points_hand_computed() -> None:
    # At t = 25 s the phase is 1/4: heading A/2, rate at its peak A*pi/T.
    heading, rate = paper(25.0)
    assert heading == pytest.approx(DEG45 / 2, abs=1e-12)
    assert rate == pytest.approx(DEG45 * math.pi / 60.0, abs=1e-12)
    heading, rate = paper(55.0)
    assert heading == pytest.approx(DEG45 / 2, abs=1e-12)
    assert rate == pytest.approx(-DEG45 * math.pi / 60.0, abs=1e-12)


def test_rate_sign_out_and_back() -> None:
    assert all(paper(t)[1] > 0 for t in (11.0, 20.0, 30.0, 39.0))
    assert all(paper(t)[1] < 0 for t in (41.0, 50.0, 60.0, 69.0))


def test_symmetric_about_the_peak() -> None:
    for dt in (0.5, 7.0, 19.0, 29.5):
        up, down = paper(40.0 - dt), paper(40.0 + dt)
        assert up[0] == pytest.approx(down[0], abs=1e-12)
        assert up[1] == pytest.approx(-down[1], abs=1e-12)


@pytest.mark.parametrize("edge", [10.0, 40.0, 70.0])
def test_continuous_at_edges(edge: float) -> None:
    eps = 1e-7
    before, at, after = paper(edge - eps), paper(edge), paper(edge + eps)
    for i in (0, 1):
        assert before[i] == pytest.approx(at[i], abs=1e-6)
        assert after[i] == pytest.approx(at[i], abs=1e-6)


def test_continuous_everywhere() -> None:
    dt = 0.001
    steps = [paper(-1.0 + dt * k) for k in range(82_000)]  # -1 s .. 81 s
    max_rate = DEG45 * math.pi / 60.0
    for (h0, r0), (h1, r1) in itertools.pairwise(steps):
        assert abs(h1 - h0) <= max_rate * dt * 1.0001 + 1e-15
        assert abs(r1 - r0) <= 1e-5


@given(st.floats(10.0 + 1e-3, 70.0 - 1e-3))
def test_rate_matches_numeric_derivative(t: float) -> None:
    h = 1e-5
    numeric = (paper(t + h)[0] - paper(t - h)[0]) / (2 * h)
    assert paper(t)[1] == pytest.approx(numeric, abs=1e-7)


@given(st.floats(-1e3, 1e3))
def test_heading_within_range(t: float) -> None:
    heading, rate = paper(t)
    assert 0.0 <= heading <= DEG45 + 1e-15
    assert abs(rate) <= DEG45 * math.pi / 60.0 + 1e-15


def test_custom_maneuver() -> None:
    m = ReferenceManeuver(start=0.0, duration=4.0, amplitude=-2.0)
    assert m(-0.1) == (0.0, 0.0)
    assert m(2.0)[0] == pytest.approx(-2.0, abs=1e-12)
    assert m(1.0)[0] == pytest.approx(-1.0, abs=1e-12)
    assert m(1.0)[1] == pytest.approx(-2.0 * math.pi / 4.0, abs=1e-12)
    assert m(4.1) == (0.0, 0.0)


def test_maneuver_is_frozen() -> None:
    with pytest.raises(AttributeError):
        paper.start = 0.0  # type: ignore[misc]


# ------------------------------------------------------------- track_heading


def test_track_heading_nothing_received_holds_zero() -> None:
    assert track_heading(None) == (0.0, 0.0)


def test_track_heading_uses_heading_and_omega() -> None:
    sample = PoseSample(t=12.0, pose=Pose(x=1.0, y=2.0, heading=0.6, vx=3.0, vy=4.0, omega=-0.02))
    assert track_heading(sample) == (0.6, -0.02)


@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-1e3, 1e3))
def test_track_heading_ignores_everything_else(heading: float, omega: float, t: float) -> None:
    sample = PoseSample(t, Pose(x=t, y=-t, heading=heading, vx=7.0, vy=8.0, omega=omega))
    assert track_heading(sample) == (heading, omega)


# ---------------------------------------------------------- KinematicPlatform


def test_kinematic_platform_initial_pose() -> None:
    assert KinematicPlatform().pose == Pose()
    assert KinematicPlatform(x=1.5, y=-0.5).pose == Pose(x=1.5, y=-0.5)


def test_kinematic_platform_follows_command() -> None:
    platform = KinematicPlatform(x=1.5, y=0.8)
    pose = platform.step(1.0, heading_ref=0.3, rate_ref=0.01)
    assert pose == Pose(x=1.5, y=0.8, heading=0.3, vx=0.0, vy=0.0, omega=0.01)
    assert platform.pose == pose
    pose = platform.step(2.0, heading_ref=-0.1, rate_ref=-0.2)
    assert pose.heading == -0.1
    assert pose.omega == -0.2
    assert (pose.x, pose.y, pose.vx, pose.vy) == (1.5, 0.8, 0.0, 0.0)


def test_kinematic_platform_tracks_the_reference_maneuver() -> None:
    platform = KinematicPlatform()
    for k in range(801):
        t = 0.1 * k
        heading_ref, rate_ref = paper(t)
        pose = platform.step(t, heading_ref, rate_ref)
        assert pose.heading == heading_ref
        assert pose.omega == rate_ref
    assert platform.pose.heading == 0.0  # back at rest after 70 s


def test_follower_chain_reproduces_leader() -> None:
    """Leader flies the maneuver; a follower tracking its samples has the same heading."""
    leader, follower = KinematicPlatform(), KinematicPlatform(x=3.0)
    for k in range(0, 800, 7):
        t = 0.1 * k
        sample = PoseSample(t, leader.step(t, *paper(t)))
        pose = follower.step(t, *track_heading(sample))
        assert pose.heading == sample.pose.heading
        assert pose.omega == sample.pose.omega
        assert pose.x == 3.0


@pytest.mark.parametrize("duration", [0.0, -1.0, float("nan")])
def test_maneuver_needs_positive_duration(duration: float) -> None:
    with pytest.raises(ValueError, match="duration"):
        ReferenceManeuver(duration=duration)


# ---------------------------------------------------------- HeadingEstimator

SIGMA_HEADING, SIGMA_RATE = 0.0007, 0.003  # rad, rad/s: a shared pose's noise (rehearsal)


def _stream(
    delay: float, seed: int, sender: Any = paper, until: float = 75.0, noise: bool = True
) -> list[tuple[float, PoseSample]]:
    """The sender's samples of ``sender`` at 20 Hz (with a shared pose's noise), each with
    the time it arrives ``delay`` s later (simulated time, the sender's clock)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(round(until * 20) + 1):
        t = k * 0.05
        heading, rate = sender(t)
        if noise:
            heading += float(rng.normal(0.0, SIGMA_HEADING))
            rate += float(rng.normal(0.0, SIGMA_RATE))
        out.append((t + delay, PoseSample(t, Pose(heading=heading, omega=rate))))
    return out


def _follow(
    stream: list[tuple[float, PoseSample]],
    reference: Any,
    until: float = 75.0,
) -> list[tuple[float, float, float]]:
    """(now, heading, rate) references every 10 ms from the latest sample arrived."""
    out, latest, i = [], None, 0
    for k in range(round(until * 100) + 1):
        now = k * 0.01
        while i < len(stream) and stream[i][0] <= now + 1e-12:
            latest, i = stream[i][1], i + 1
        if latest is not None:
            out.append((now, *reference(latest, now)))
    return out


def _estimated(estimator: HeadingEstimator, sender: Any = paper) -> Any:
    # On the sender's clock, run time is reference time here: run_time = now.
    return lambda sample, now: estimator.reference(sample, now, True, sender, now)


def test_estimator_nothing_received_holds_zero() -> None:
    assert HeadingEstimator().reference(None, 3.0, True, paper, 3.0) == (0.0, 0.0)


@given(st.floats(-3, 3), st.floats(-1, 1), st.floats(0, 100), st.floats(0, 2) | st.none())
def test_estimator_without_compensation_is_the_sample(
    heading: float, omega: float, t: float, age: float | None
) -> None:
    sample = PoseSample(t, Pose(heading=heading, omega=omega))
    now = None if age is None else t + age
    assert HeadingEstimator().reference(sample, now, False) == (heading, omega)


@given(st.floats(-3.1, 3.1), st.floats(-0.5, 0.5), st.floats(0, 100), st.floats(-0.5, 3.0))
def test_estimator_first_sample_is_dead_reckoned(
    heading: float, omega: float, t: float, age: float
) -> None:
    # One sample, no maneuver: as track_heading (age clamped to 0 .. horizon), wrapped.
    sample = PoseSample(t, Pose(heading=heading, omega=omega))
    got = HeadingEstimator().reference(sample, t + age)
    want = track_heading(sample, t + age)
    assert got[1] == want[1]
    assert wrap_angle(got[0] - want[0]) == pytest.approx(0.0, abs=1e-9)
    assert -math.pi < got[0] <= math.pi


@settings(max_examples=8, deadline=None)
@given(st.floats(0.0, 0.9))
def test_estimator_is_exact_on_a_sender_flying_the_maneuver(delay: float) -> None:
    # Noise-free samples of the maneuver: every innovation is 0 and the reference is the
    # maneuver at now, whatever the delay (within the horizon).
    estimator = HeadingEstimator()
    got = _follow(_stream(delay, 0, noise=False), _estimated(estimator))
    assert got and got[0][0] == pytest.approx(delay, abs=0.01)
    for now, heading, rate in got:
        assert heading == pytest.approx(paper(now)[0], abs=1e-9), now
        assert rate == pytest.approx(paper(now)[1], abs=1e-9), now
    assert estimator.restarts == 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_estimator_reference_is_closer_and_smoother_than_dead_reckoning(seed: int) -> None:
    # Samples of the maneuver with a shared pose's noise; each reference against the
    # maneuver at now (the sender's truth), the filter's beside dead reckoning's.
    def scores(delay: float, reference: Any) -> tuple[float, float, float]:
        got = np.array(_follow(_stream(delay, seed), reference))
        truth = np.array([paper(now) for now in got[:, 0]])
        heading, rate = got[:, 1] - truth[:, 0], got[:, 2] - truth[:, 1]
        step = float(np.max(np.abs(np.diff(heading))))  # beyond the maneuver's own motion
        return float(np.sqrt(np.mean(heading**2))), float(np.sqrt(np.mean(rate**2))), step

    rates = []
    for delay in (0.04, 0.25):
        dr = scores(delay, lambda sample, now: track_heading(sample, now))
        kf = scores(delay, _estimated(HeadingEstimator()))
        print(f"{delay * 1e3:.0f} ms, seed {seed}: heading RMS, rate RMS, largest step")
        print(f"  dead reckoning {dr[0]:.2e} rad {dr[1]:.2e} rad/s {dr[2]:.2e} rad")
        print(f"  estimator      {kf[0]:.2e} rad {kf[1]:.2e} rad/s {kf[2]:.2e} rad")
        assert kf[0] < dr[0] / 2  # measured: 2.3 times smaller
        assert kf[1] < dr[1] / 3  # 3.4 to 3.6 times
        assert kf[2] < dr[2] / 3  # 3.6 to 6.7 times
        rates.append(kf[1])
    assert rates[1] < 1.1 * rates[0]  # the rate reference does not lag by the delay


@pytest.mark.parametrize("delay", [0.04, 0.25])
def test_estimator_follows_the_sender_not_the_maneuver(delay: float) -> None:
    # The sender holds still while the maneuver it was to fly turns 45 deg: the
    # reference stays on the sender (measured: within 0.06 and 0.10 deg).
    got = _follow(_stream(delay, 0, sender=lambda t: (0.0, 0.0)), _estimated(HeadingEstimator()))
    assert max(abs(heading) for _, heading, _ in got) < math.radians(0.2)
    assert max(abs(rate) for _, _, rate in got) < math.radians(0.5)


@pytest.mark.parametrize("delay", [0.04, 0.25])
def test_estimator_takes_a_jump_in_steps_of_a_gain(delay: float) -> None:
    # The followed heading jumps by 0.2 rad at 30 s (another sender takes the role): the
    # reference moves at most a quarter of it in a 10 ms step and is within 0.01 rad of
    # it 1 s after it arrived (measured: 0.037 and 0.053 rad; 0.48 and 0.79 s).
    def sender(t: float) -> tuple[float, float]:
        heading, rate = paper(t)
        return heading + (0.2 if t >= 30.0 else 0.0), rate

    got = _follow(_stream(delay, 0, sender=sender), _estimated(HeadingEstimator()))
    beyond = [heading - paper(now)[0] for now, heading, _ in got]
    assert max(abs(b - a) for a, b in itertools.pairwise(beyond)) < 0.05 + 0.01 * (delay > 0.1)
    late = [abs(h - sender(now)[0]) for now, h, _ in got if now >= 30.0 + delay + 1.0]
    assert late and max(late) < 0.01


def test_estimator_takes_no_older_or_repeated_sample() -> None:
    estimator = HeadingEstimator()
    first, second = PoseSample(1.0, Pose(heading=0.1)), PoseSample(1.05, Pose(heading=0.12))
    estimator.reference(first, 1.05)
    estimator.reference(second, 1.1)
    state = (estimator.t, estimator.x, estimator.p)
    for sample in (first, second, PoseSample(1.02, Pose(heading=3.0))):  # reordered
        estimator.reference(sample, 1.1)
        assert (estimator.t, estimator.x, estimator.p) == state


NONFINITE = st.sampled_from([math.nan, math.inf, -math.inf])


@given(NONFINITE, st.sampled_from(["t", "heading", "omega", "now", "run_time"]))
def test_estimator_nonfinite_input_gives_nan_and_leaves_the_filter(bad: float, where: str) -> None:
    # A NaN reference is what the GNC chain closes every valve on ("nonfinite"); the
    # filter goes on from the samples before it as if it never came.
    clean, faulted = HeadingEstimator(), HeadingEstimator()
    for k in range(10):
        sample = PoseSample(k * 0.05, Pose(heading=0.01 * k, omega=0.2))
        assert clean.reference(sample, k * 0.05 + 0.04, True, paper, 1.0) == faulted.reference(
            sample, k * 0.05 + 0.04, True, paper, 1.0
        )
    fields = {"t": 0.5, "heading": 0.1, "omega": 0.2, "now": 0.54, "run_time": 1.0}
    fields[where] = bad
    sample = PoseSample(fields["t"], Pose(heading=fields["heading"], omega=fields["omega"]))
    got = faulted.reference(sample, fields["now"], True, paper, fields["run_time"])
    assert all(map(math.isnan, got))
    good = PoseSample(0.5, Pose(heading=0.1, omega=0.2))
    assert faulted.reference(good, 0.54, True, paper, 1.0) == clean.reference(
        good, 0.54, True, paper, 1.0
    )


@given(st.floats(1.0, 1e4))
def test_estimator_predicts_no_further_than_its_horizon(age: float) -> None:
    estimator = HeadingEstimator()
    sample = PoseSample(2.0, Pose(heading=0.3, omega=0.1))
    at_horizon = estimator.reference(sample, 2.0 + HeadingFilter().horizon)
    assert estimator.reference(sample, 2.0 + age) == at_horizon
    assert at_horizon == pytest.approx((0.4, 0.1))


def test_estimator_starts_afresh_after_a_gap() -> None:
    estimator = HeadingEstimator()
    for k in range(20):
        estimator.reference(PoseSample(k * 0.05, Pose(heading=0.5, omega=0.0)), k * 0.05)
    assert estimator.restarts == 1
    after = PoseSample(0.95 + 1.5, Pose(heading=-0.4, omega=0.05))  # 1.5 s without samples
    assert estimator.reference(after, after.t) == (-0.4, 0.05)
    assert estimator.restarts == 2
    back = PoseSample(0.2, Pose(heading=1.0, omega=0.0))  # the sender's clock went back
    assert estimator.reference(back, 0.2) == (1.0, 0.0)
    assert estimator.restarts == 3


def test_estimator_turns_through_pi_without_a_step() -> None:
    # A sender turning at 0.3 rad/s for 30 s crosses +-pi three times (wrapped samples).
    def turning(t: float) -> tuple[float, float]:
        return wrap_angle(0.3 * t), 0.3

    estimator = HeadingEstimator()  # no maneuver: a constant rate
    stream = _stream(0.25, 0, sender=turning, until=30.0)
    got = _follow(stream, lambda sample, now: estimator.reference(sample, now), until=30.0)
    assert all(abs(wrap_angle(h - 0.3 * now)) < 0.005 for now, h, _ in got if now > 1.0)
    headings = [heading for _, heading, _ in got]
    assert all(-math.pi < h <= math.pi for h in headings)
    assert max(abs(wrap_angle(b - a)) for a, b in itertools.pairwise(headings)) < 0.01
    now, heading, rate = got[-1]
    assert wrap_angle(heading - 0.3 * now) == pytest.approx(0.0, abs=0.005)
    assert rate == pytest.approx(0.3, abs=0.01)


@pytest.mark.parametrize(
    "field", ["heading_noise", "rate_noise", "acceleration_noise", "horizon", "restart_after"]
)
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_heading_filter_refuses_a_bad_setting(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=f"HeadingFilter.{field}"):
        HeadingFilter(**{field: value})


def test_estimator_takes_no_rate_its_headings_do_not_show() -> None:
    # 50 rad/s from a sender whose heading stands still: the rate is left out (counted)
    # and the reference stays on the heading; dead reckoning's stays too (age 0 here),
    # but a filter taking the rate would have dragged its heading 11 rad on.
    estimator = HeadingEstimator()
    for k in range(600):
        t = k * 0.01
        got = estimator.reference(PoseSample(t, Pose(omega=50.0 if t >= 1 else 0.0)), t)
        assert abs(got[0]) < 1e-3 and abs(got[1]) < 1e-2, t
    assert estimator.rates_rejected == 500


@pytest.mark.parametrize("delay", [0.04, 0.25])
def test_estimator_follows_a_turn_that_starts_at_once(delay: float) -> None:
    # Still, then 0.3 rad/s from 5 s on (a step no platform flies): the first rates are
    # left out, the headings bring the filter on; within 0.01 rad and rad/s 1 s after
    # the turn arrived (measured: 0.64 s), no 10 ms step over 0.02 rad.
    def sender(t: float) -> tuple[float, float]:
        return (0.0, 0.0) if t < 5.0 else (wrap_angle(0.3 * (t - 5.0)), 0.3)

    estimator = HeadingEstimator()
    stream = _stream(delay, 0, sender=sender, until=15.0)
    got = _follow(stream, lambda sample, now: estimator.reference(sample, now), until=15.0)
    assert estimator.rates_rejected > 0
    for now, heading, rate in got:
        if now >= 5.0 + delay + 1.0 or now < 5.0:
            assert abs(wrap_angle(heading - sender(now)[0])) < 0.01, now
            assert abs(rate - sender(now)[1]) < 0.01, now
    assert max(abs(wrap_angle(b[1] - a[1])) for a, b in itertools.pairwise(got)) < 0.02

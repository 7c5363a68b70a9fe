"""Guidance and the kinematic platform (agents/guidance.py, agents/kinematic.py)."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from agents import KinematicPlatform, ReferenceManeuver, track_heading
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

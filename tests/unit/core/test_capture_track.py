"""The position capture (federation/core/track_capture.py), on simulated time: a joining
platform's position reference never asks more speed or acceleration than its preset's
limits, has no step, meets reachable targets (still, moving, circling within the
limits) and then passes them through; non-finite input gives a NaN reference (the GNC
chain closes every valve on it). And the docking keep-out a rejoining chaser is judged
by."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from federation.core.capture import Capture, Limits
from federation.core.track_capture import (
    BRAKE_SHARE,
    POSITION_TOL,
    VELOCITY_TOL,
    Setpoint,
    TrackCapture,
    TrackLimits,
    docking_keep_out,
)
from schemas.platform import load_platform
from schemas.scenario import MAX_PATH_SPEED

DT = 0.01
EPS = 1e-12

Target = Callable[[float], Setpoint]
Path = list[tuple[Setpoint, bool]]


def _limits(preset: str) -> TrackLimits:
    p = load_platform(preset)
    return TrackLimits(MAX_PATH_SPEED, p.thrust / p.mass)


def _circle(radius: float, period: float, cx: float = 0.0, cy: float = 0.0) -> Target:
    w = 2 * math.pi / period

    def at(t: float) -> Setpoint:
        c, s = math.cos(w * t), math.sin(w * t)
        return Setpoint(
            cx + radius * c, cy + radius * s, -radius * w * s, radius * w * c,
            -radius * w * w * c, -radius * w * w * s,
        )  # fmt: skip

    return at


def _line(x0: float, y0: float, vx: float, vy: float) -> Target:
    return lambda t: Setpoint(x0 + vx * t, y0 + vy * t, vx, vy)


def _fly(capture: TrackCapture, target: Target, seconds: float) -> Path:
    out = []
    for k in range(1, int(seconds / DT) + 1):
        out.append((capture.step(target(k * DT), DT), capture.captured))
    return out


def _check_limits(
    start: tuple[float, float, float, float], path: Path, limits: TrackLimits
) -> None:
    """Before capture: speed and acceleration within the limits, position and velocity
    continuous (no step), the acceleration given the one flown."""
    px, py, pvx, pvy = start
    for ref, captured in path:
        if captured:
            break
        assert math.hypot(ref.vx, ref.vy) <= limits.max_speed + EPS
        assert math.hypot(ref.ax, ref.ay) <= limits.max_accel * (1 + 1e-9)
        assert math.hypot(ref.vx - pvx, ref.vy - pvy) <= limits.max_accel * DT * (1 + 1e-9)
        assert ref.vx - pvx == pytest.approx(ref.ax * DT, abs=1e-12)
        assert math.hypot(ref.x - px, ref.y - py) <= limits.max_speed * DT + EPS
        px, py, pvx, pvy = ref.x, ref.y, ref.vx, ref.vy


def _captured_at(path: Path) -> float:
    assert path[-1][1], "never captured"
    return next(k for k, (_, c) in enumerate(path) if c) * DT


@pytest.mark.parametrize("preset", ["knatte", "pinocchio", "generic"])
@pytest.mark.parametrize(
    "start", [(0.0, 0.0, 0.0, 0.0), (1.2, -0.8, 0.0, 0.0), (-0.5, 0.3, 0.05, -0.04)]
)
def test_a_formation_slot_on_its_circle_is_captured_within_the_limits(
    preset: str, start: tuple[float, float, float, float]
) -> None:
    # The formation experiment's centre: 0.4 m radius, 50 s a turn (5 cm/s, 6.3 mm/s^2).
    limits = _limits(preset)
    target = _circle(0.4, 50.0, 0.3, 0.1)
    capture = TrackCapture(*start, limits)
    path = _fly(capture, target, 120.0)
    _check_limits(start, path, limits)
    took = _captured_at(path)
    print(f"{preset} from {start}: captured after {took:.1f} s")
    # Bounded: the braking curve's time over the distance, twice, and a margin.
    d = math.hypot(start[0] - target(0).x, start[1] - target(0).y) + 0.5
    assert took <= 4 * math.sqrt(2 * d / (BRAKE_SHARE * limits.max_accel)) + 10
    ref, _ = path[-1]
    assert ref == target(len(path) * DT)  # passed through unchanged


def test_once_captured_the_scenario_passes_through_unchanged() -> None:
    capture = TrackCapture(0.0, 0.0, 0.0, 0.0, _limits("knatte"))
    _fly(capture, lambda t: Setpoint(0.1, 0.0, 0.0, 0.0), 30.0)
    assert capture.captured
    odd = Setpoint(5.0, -3.0, 0.2, 0.1, 0.01, -0.02)
    assert capture.step(odd, DT) == odd


def test_a_reference_already_there_is_captured_at_once() -> None:
    capture = TrackCapture(0.2, 0.3, 0.0, 0.0, _limits("knatte"))
    ref = capture.step(Setpoint(0.2, 0.3, 0.0, 0.0), DT)
    assert capture.captured and ref == Setpoint(0.2, 0.3, 0.0, 0.0, 0.0, 0.0)


def test_a_speed_beyond_the_limit_is_clipped_first() -> None:
    capture = TrackCapture(0.0, 0.0, 3.0, 4.0, TrackLimits(0.5, 0.02))
    assert math.hypot(capture.vx, capture.vy) == pytest.approx(0.5)


def test_no_overshoot_onto_a_still_point() -> None:
    # Braking at half the acceleration, from rest: the reference never passes the point.
    limits = _limits("knatte")
    capture = TrackCapture(0.0, 0.0, 0.0, 0.0, limits)
    path = _fly(capture, lambda t: Setpoint(1.0, 0.0, 0.0, 0.0), 60.0)
    assert max(ref.x for ref, _ in path) <= 1.0 + POSITION_TOL
    assert _captured_at(path) < 60.0


@pytest.mark.parametrize(
    "bad",
    [
        Setpoint(math.nan, 0.0, 0.0, 0.0),
        Setpoint(0.0, math.inf, 0.0, 0.0),
        Setpoint(0.0, 0.0, math.nan, 0.0),
        Setpoint(0.0, 0.0, 0.0, 0.0, ax=math.nan),
    ],
)
def test_a_non_finite_target_gives_nan_and_leaves_the_capture_as_it_was(bad: Setpoint) -> None:
    capture = TrackCapture(0.0, 0.0, 0.01, 0.0, _limits("knatte"))
    capture.step(Setpoint(1.0, 0.0, 0.0, 0.0), DT)
    state = (capture.x, capture.y, capture.vx, capture.vy)
    ref = capture.step(bad, DT)
    assert all(math.isnan(v) for v in ref)
    assert (capture.x, capture.y, capture.vx, capture.vy) == state and not capture.captured
    after = capture.step(Setpoint(1.0, 0.0, 0.0, 0.0), DT)  # from where it was, no step
    assert math.hypot(after.x - state[0], after.y - state[1]) <= 0.5 * DT + EPS


@pytest.mark.parametrize("dt", [math.nan, math.inf, -0.01])
def test_a_bad_dt_gives_nan(dt: float) -> None:
    capture = TrackCapture(0.0, 0.0, 0.0, 0.0, _limits("knatte"))
    assert all(math.isnan(v) for v in capture.step(Setpoint(1.0, 0.0, 0.0, 0.0), dt))


def test_a_non_finite_start_gives_nan_until_it_is_dropped() -> None:
    capture = TrackCapture(math.nan, 0.0, 0.0, 0.0, _limits("knatte"))
    for _ in range(3):
        assert all(math.isnan(v) for v in capture.step(Setpoint(0.0, 0.0, 0.0, 0.0), DT))
    assert not capture.captured


@pytest.mark.parametrize(
    ("speed", "accel"), [(0.0, 0.02), (-1.0, 0.02), (math.nan, 0.02), (0.5, math.inf)]
)
def test_limits_must_be_positive_numbers(speed: float, accel: float) -> None:
    with pytest.raises(ValueError, match="must be a positive number"):
        TrackLimits(speed, accel)


def test_the_heading_capture_fails_closed_on_nan_too() -> None:
    # Python's min/max would take a NaN error for the largest rate: a finite reference
    # turning at max_rate toward nothing. It gives NaN instead, state unchanged.
    for target, rate, dt in [(math.nan, 0.0, DT), (0.1, math.nan, DT), (0.1, 0.0, math.nan)]:
        capture = Capture(0.0, 0.0, Limits(0.5, 0.2))
        out = capture.step(target, rate, dt)
        assert math.isnan(out[0]) and math.isnan(out[1])
        assert (capture.heading, capture.rate) == (0.0, 0.0) and not capture.captured


_coord = st.floats(-2.0, 2.0)
_vel = st.floats(-0.1, 0.1)


@settings(max_examples=150, deadline=None)
@given(
    st.tuples(_coord, _coord, _vel, _vel),
    st.lists(st.tuples(_coord, _coord, _vel, _vel, _vel, _vel), min_size=1, max_size=60),
    st.sampled_from(["knatte", "pinocchio", "generic"]),
)
def test_any_targets_even_jumping_ones_never_make_a_step(
    start: tuple[float, float, float, float],
    targets: list[tuple[float, float, float, float, float, float]],
    preset: str,
) -> None:
    limits = _limits(preset)
    capture = TrackCapture(*start, limits)
    path = []
    for t in targets:
        path.append((capture.step(Setpoint(*t), DT), capture.captured))
    _check_limits(start, path, limits)


@settings(max_examples=25, deadline=None)
@given(
    st.tuples(_coord, _coord, st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)),
    st.floats(0.1, 0.6),
    st.floats(40.0, 120.0),
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
)
def test_a_target_moving_within_the_limits_is_always_captured(
    start: tuple[float, float, float, float],
    radius: float,
    period: float,
    cx: float,
    cy: float,
) -> None:
    # Within the limits: the target's acceleration (r w^2) at most the share the braking
    # leaves, its speed far under max_speed.
    limits = _limits("pinocchio")  # the weakest preset: 15 mm/s^2
    target = _circle(radius, period, cx, cy)
    assume(radius * (2 * math.pi / period) ** 2 <= (1 - BRAKE_SHARE) * limits.max_accel)
    capture = TrackCapture(*start, limits)
    path = _fly(capture, target, 150.0)
    _check_limits(start, path, limits)
    assert path[-1][1], "never captured"
    ref, _ = path[-1]
    t = len(path) * DT
    assert math.hypot(ref.x - target(t).x, ref.y - target(t).y) == 0.0


@pytest.mark.parametrize("v", [(0.05, 0.0), (-0.03, 0.04), (0.2, 0.2)])
def test_a_target_on_a_straight_line_is_captured(v: tuple[float, float]) -> None:
    limits = _limits("knatte")
    path = _fly(TrackCapture(0.0, 0.0, 0.0, 0.0, limits), _line(0.5, -0.5, *v), 200.0)
    _check_limits((0.0, 0.0, 0.0, 0.0), path, limits)
    assert _captured_at(path) < 200.0


def test_at_capture_the_reference_is_within_the_tolerances_of_the_scenario() -> None:
    limits = _limits("generic")
    target = _circle(0.4, 50.0)
    capture = TrackCapture(1.0, 1.0, 0.0, 0.0, limits)
    k = 0
    while not capture.captured:
        k += 1
        ref = capture.step(target(k * DT), DT)
        assert k < 20_000
    nxt = target((k + 1) * DT)
    assert math.hypot(nxt.x - ref.x, nxt.y - ref.y) <= POSITION_TOL + 0.1 * DT
    assert math.hypot(nxt.vx - ref.vx, nxt.vy - ref.vy) <= VELOCITY_TOL + 0.01 * DT


# -- the docking keep-out ------------------------------------------------------------
L, H, BRAKE = 0.5, 0.3, 0.015


def test_a_chaser_beyond_the_hold_point_on_the_axis_may_rejoin() -> None:
    # The docking experiment's start: 1.3 m out on the target's port axis.
    assert docking_keep_out((1.3, 0.1, 0.0, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE) is None


def test_a_chaser_in_its_final_approach_is_refused() -> None:
    why = docking_keep_out((0.7, 0.0, -0.01, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE)
    assert why is not None and "inside the hold point's 0.80 m" in why and "no rejoin" in why


def test_a_chaser_behind_the_target_is_refused_its_way_crosses_the_keep_out() -> None:
    why = docking_keep_out((-1.5, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE)
    assert why is not None and "keep-out" in why


def test_a_chaser_beside_the_target_clears_it() -> None:
    # From (0, 1) to the hold point (0.8, 0): 0.62 m from the target's centre at nearest.
    assert docking_keep_out((0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE) is None


def test_a_chaser_coasting_toward_the_target_is_judged_where_it_stops() -> None:
    # 1.0 m out, but at 0.2 m/s toward the target: it stops 1.33 m further on, across it.
    why = docking_keep_out((1.0, 0.0, -0.2, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE)
    assert why is not None and "keep-out" in why
    assert docking_keep_out((1.0, 0.0, 0.2, 0.0), (0.0, 0.0, 0.0), L, H, BRAKE) is None


def test_the_target_s_heading_places_the_port() -> None:
    # The port faces -x: a chaser at +x must go round the target to it.
    assert docking_keep_out((1.3, 0.0, 0.0, 0.0), (0.0, 0.0, math.pi), L, H, BRAKE) is not None
    assert docking_keep_out((-1.3, 0.0, 0.0, 0.0), (0.0, 0.0, math.pi), L, H, BRAKE) is None


@pytest.mark.parametrize(
    ("chaser", "target"),
    [((math.nan, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), ((1.3, 0.0, 0.0, 0.0), (0.0, math.inf, 0.0))],
)
def test_a_non_finite_pose_is_refused(
    chaser: tuple[float, float, float, float], target: tuple[float, float, float]
) -> None:
    why = docking_keep_out(chaser, target, L, H, BRAKE)
    assert why is not None and "not finite" in why

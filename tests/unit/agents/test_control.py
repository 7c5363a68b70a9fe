"""PID, PWM, thruster allocation and position hold (agents/control.py)."""

from __future__ import annotations

import math

import control as ct
import pytest

from agents.control import HeadingPid, PositionHold, PulseWidthModulator, allocate
from agents.dynamics import PAIRS
from federation.core.wire import Pose
from schemas.platform import load_platform

DEG = math.radians(1.0)


def pid(kp: float = 0.2, ki: float = 0.0, kd: float = 0.0, limit: float = 0.064) -> HeadingPid:
    return HeadingPid(kp, ki, kd, limit=limit, integral_limit=0.01)


# ---------------------------------------------------------------- PID (Eq. 1, 2)


def test_torque_opposes_the_error() -> None:
    # Eq. 1: e = heading - heading_ref = +10 deg; Eq. 2 with the torque opposing it
    assert pid().update(0.0, 10 * DEG, 0.0, 0.0, 0.0) == pytest.approx(-0.2 * 10 * DEG)
    assert pid().update(0.0, 0.0, 0.0, 10 * DEG, 0.0) == pytest.approx(0.2 * 10 * DEG)


def test_derivative_on_rate_error_with_feed_forward() -> None:
    c = pid(kp=0.0, kd=0.35)
    assert c.update(0.0, 0.0, 0.05, 0.0, 0.0) == pytest.approx(-0.35 * 0.05)
    assert c.update(0.01, 0.0, 0.05, 0.0, 0.05) == 0.0  # rate matches the reference rate
    assert c.update(0.02, 0.0, 0.0, 0.0, 0.05) == pytest.approx(0.35 * 0.05)


def test_error_is_wrapped() -> None:
    # 179 deg vs -179 deg: 2 deg apart, not 358
    torque = pid().update(0.0, 179 * DEG, 0.0, -179 * DEG, 0.0)
    assert torque == pytest.approx(0.2 * 2 * DEG)
    assert pid().update(0.0, 2 * math.pi + DEG, 0.0, 0.0, 0.0) == pytest.approx(-0.2 * DEG)


def test_output_saturates_at_the_pair_torque() -> None:
    assert pid().update(0.0, 90 * DEG, 0.0, 0.0, 0.0) == -0.064
    assert pid().update(0.0, -90 * DEG, 0.0, 0.0, 0.0) == 0.064


def test_integral_term() -> None:
    c = pid(kp=0.0, ki=0.03)
    c.update(0.0, DEG, 0.0, 0.0, 0.0)
    for k in range(1, 101):
        torque = c.update(k * 0.01, DEG, 0.0, 0.0, 0.0)
    assert c.integral == pytest.approx(DEG * 1.0)
    assert torque == pytest.approx(-0.03 * DEG)


def test_integral_clamped_to_its_limit() -> None:
    c = pid(kp=0.0, ki=0.03)
    for k in range(10_000):  # 100 s at 5 deg
        torque = c.update(k * 0.01, 5 * DEG, 0.0, 0.0, 0.0)
    assert torque == pytest.approx(-0.01)  # integral_limit, Nm
    assert c.integral == pytest.approx(0.01 / 0.03)


def test_no_windup_while_saturated() -> None:
    """Conditional integration: a long saturated stretch leaves the integral alone."""
    c = HeadingPid(0.2, 0.03, 0.0, limit=0.064, integral_limit=1.0)
    for k in range(5000):  # 50 s saturated at 30 deg
        c.update(k * 0.01, 30 * DEG, 0.0, 0.0, 0.0)
    assert c.saturated
    assert c.integral == 0.0
    # without anti-windup the integral would hold 30 deg x 50 s = 26 rad s
    assert c.update(50.0, 0.0, 0.0, 0.0, 0.0) == 0.0


def test_reset() -> None:
    c = pid(kp=0.0, ki=0.03)
    for k in range(100):
        c.update(k * 0.01, DEG, 0.0, 0.0, 0.0)
    c.reset()
    assert c.integral == 0.0
    assert c.update(5.0, DEG, 0.0, 0.0, 0.0) == 0.0  # first call after reset: dt = 0


def test_bad_limit() -> None:
    with pytest.raises(ValueError, match="torque limit"):
        HeadingPid(1, 0, 0, limit=0.0, integral_limit=0.0)


# ---------------------------------------------------------------- PWM


def pulses(pwm: PulseWidthModulator, duty: float, periods: int, t0: float = 0.0) -> list[int]:
    n = round(periods * pwm.period / pwm.tick)
    return [pwm.update(t0 + k * pwm.tick, [duty])[0] for k in range(n)]


def test_pwm_on_time_within_a_period() -> None:
    pwm = PulseWidthModulator(period=0.1, min_on_time=0.01, tick=0.01)
    assert pulses(pwm, 0.3, 2) == [1, 1, 1, 0, 0, 0, 0, 0, 0, 0] * 2
    pwm = PulseWidthModulator(period=0.1, min_on_time=0.01, tick=0.01)
    assert pulses(pwm, -0.5, 1) == [-1] * 5 + [0] * 5
    assert pulses(pwm, 1.0, 1, t0=0.1) == [1] * 10
    assert pulses(pwm, 0.0, 1, t0=0.2) == [0] * 10


@pytest.mark.parametrize("duty", [0.35, 0.07, -0.123, 0.013, 0.999])
def test_pwm_mean_equals_the_demand(duty: float) -> None:
    """Rounding and sub-minimum residues are carried: the mean is right at any duty."""
    pwm = PulseWidthModulator(period=0.1, min_on_time=0.03, tick=0.01)
    out = pulses(pwm, duty, 300)
    assert sum(out) / len(out) == pytest.approx(duty, abs=0.004)
    # every pulse lasts at least the minimum on-time (3 ticks)
    runs = "".join("1" if v else "0" for v in out).split("0")
    assert all(len(r) >= 3 for r in runs if r)


def test_pwm_latches_at_the_period_start() -> None:
    pwm = PulseWidthModulator(period=0.1, min_on_time=0.01, tick=0.01)
    out = [pwm.update(k * 0.01, [0.2 if k < 3 else 1.0])[0] for k in range(10)]
    assert out == [1, 1] + [0] * 8  # the demand of 1.0 waits for the next period
    assert pwm.update(0.1, [1.0]) == (1,)


def test_pwm_right_aligned_channel() -> None:
    pwm = PulseWidthModulator(0.1, 0.01, 0.01, channels=2, right_aligned=[True])
    out = [pwm.update(k * 0.01, [0.3, 0.3]) for k in range(10)]
    assert [o[0] for o in out] == [0] * 7 + [1] * 3
    assert [o[1] for o in out] == [1] * 3 + [0] * 7


def test_pwm_restarts_after_a_gap() -> None:
    pwm = PulseWidthModulator(0.1, 0.01, 0.01)
    pulses(pwm, 0.5, 1)
    assert pwm.update(7.003, [0.2]) == (1,)  # a new period starts at once
    assert pwm.update(7.013, [0.2]) == (1,)
    assert pwm.update(7.023, [0.2]) == (0,)


def test_pwm_checks() -> None:
    with pytest.raises(ValueError, match="min_on_time"):
        PulseWidthModulator(0.1, 0.1, 0.01)
    with pytest.raises(ValueError, match="period"):
        PulseWidthModulator(0.005, 0.0, 0.01)
    with pytest.raises(ValueError, match="2 demands"):
        PulseWidthModulator(0.1, 0.0, 0.01, channels=2).update(0.0, [0.1])


# ---------------------------------------------------------------- allocation


@pytest.mark.parametrize(
    ("signs", "pair"),
    [
        ((1, 0, 0), "+x"),
        ((-1, 0, 0), "-x"),
        ((0, 1, 0), "+y"),
        ((0, -1, 0), "-y"),
        ((0, 0, 1), "+torque"),
        ((0, 0, -1), "-torque"),
    ],
)
def test_allocate_opens_the_pair(signs: tuple[int, int, int], pair: str) -> None:
    valves = allocate(*signs)
    assert [i for i, v in enumerate(valves) if v] == list(PAIRS[pair])


def test_allocate_nothing_and_combinations() -> None:
    assert allocate(0, 0, 0) == (False,) * 8
    assert sum(allocate(0, 1, 1)) == 4  # y and torque use different valves
    assert sum(allocate(1, 0, 1)) == 3  # x and torque share valve 1


# ---------------------------------------------------------------- position hold


def test_position_hold_in_the_body_frame() -> None:
    hold = PositionHold(kp=2.5, kd=9.0, limit=0.4, target=(0.0, 0.0))
    # 1 cm east of the target, facing north: push west, which is body +y
    fx, fy = hold.update(Pose(x=0.01, heading=math.pi / 2))
    assert fx == pytest.approx(0.0, abs=1e-12)
    assert fy == pytest.approx(0.025)
    fx, fy = hold.update(Pose(vx=-0.01))  # moving west, facing east: brake, push east
    assert (fx, fy) == pytest.approx((0.09, 0.0))
    assert hold.update(Pose(x=-1.0)) == (0.4, 0.0)  # saturated at the pair's force


# ---------------------------------------------------------------- the shipped gains


@pytest.mark.parametrize("name", ["knatte", "pinocchio"])
def test_shipped_gains_have_margin(name: str) -> None:
    """Heading loop PID x 1/(I s^2), PWM as its mean torque: phase margin and delay margin."""
    config = load_platform(name)
    c = config.control
    s = ct.tf("s")
    loop = (c.kp + c.ki / s + c.kd * s) / (config.inertia * s**2)
    _, phase_margin, _, crossover = ct.margin(loop)
    delay_margin = math.radians(phase_margin) / crossover
    print(
        f"\n[gains] {name}: kp {c.kp} ki {c.ki} kd {c.kd}: crossover {crossover:.2f} rad/s, "
        f"phase margin {phase_margin:.1f} deg, delay margin {delay_margin:.2f} s"
    )
    assert phase_margin > 45.0
    # the PWM period (a sample-and-hold, about half a period of delay) plus the paper's
    # 40 ms link fit well inside the delay margin
    assert delay_margin > 4 * (c.pwm_period / 2 + 0.040)

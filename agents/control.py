"""Control: heading PID (paper Eq. 1 and 2), pulse-width modulation, position control.

No I/O and no clock: every call takes the time ``now``.

The PID gives a continuous torque demand; the thrusters are on/off solenoid
valves, so :class:`PulseWidthModulator` turns demands into valve pulses and
:func:`allocate` picks the valves (geometry in :mod:`agents.dynamics`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from agents.dynamics import PAIRS, THRUSTERS
from agents.guidance import Track
from federation.core.angles import wrap_angle
from federation.core.wire import Pose

__all__ = ["HeadingPid", "PositionHold", "PulseWidthModulator", "allocate"]


def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


class HeadingPid:
    """PID on the heading error with anti-windup and torque saturation.

    Eq. 1, the error (wrapped to :math:`(-\\pi, \\pi]`) and its rate:

    .. math::

        e(t) = \\psi(t) - \\psi_{ref}(t), \\qquad \\dot e = \\omega - \\omega_{ref}

    Eq. 2, the control law; the torque opposes the error and saturates at the
    torque the thrusters give, :math:`\\tau_{max}`:

    .. math::

        u = K_p e + K_i \\int e\\,dt + K_d \\dot e, \\qquad
        \\tau = \\mathrm{sat}_{\\tau_{max}}(-u)

    Using the measured rate for :math:`\\dot e` (rather than differencing the error)
    keeps the derivative free of the reference's steps and makes
    :math:`\\omega_{ref}` a feed-forward. Anti-windup: the integral term is clamped
    to :math:`\\pm` ``integral_limit`` (Nm) and does not integrate while the output
    is saturated in the error's direction (conditional integration).

    Parameters
    ----------
    kp, ki, kd : float
        Gains, Nm/rad, Nm/(rad s), Nm s/rad.
    limit : float
        Output saturation, Nm.
    integral_limit : float
        Largest torque of the integral term, Nm.
    """

    def __init__(self, kp: float, ki: float, kd: float, limit: float, integral_limit: float):
        if not limit > 0:
            raise ValueError(f"torque limit must be positive Nm, not {limit!r}")
        self.kp, self.ki, self.kd = kp, ki, kd
        self.limit = limit
        self.integral_limit = integral_limit
        self.integral = 0.0  # rad s
        self.saturated = False
        self._t: float | None = None

    def reset(self) -> None:
        """Forget the integral and the last time (bumpless restart)."""
        self.integral = 0.0
        self.saturated = False
        self._t = None

    def update(
        self, now: float, heading: float, rate: float, heading_ref: float, rate_ref: float
    ) -> float:
        """Torque demand (Nm) at ``now`` (s) for the estimated heading and rate
        (rad, rad/s) and the reference (rad, rad/s)."""
        dt = 0.0 if self._t is None else max(0.0, now - self._t)
        self._t = now
        e = wrap_angle(heading - heading_ref)  # Eq. 1
        de = rate - rate_ref
        integral = self.integral + e * dt
        if self.ki > 0:
            bound = self.integral_limit / self.ki
            integral = _clip(integral, bound)
        u = self.kp * e + self.ki * integral + self.kd * de  # Eq. 2
        self.saturated = abs(u) > self.limit
        if self.saturated and e * u > 0:  # integrating would push further into saturation
            integral = self.integral
            u = self.kp * e + self.ki * integral + self.kd * de
        self.integral = integral
        return _clip(-u, self.limit)


class PulseWidthModulator:
    """Continuous demands to on/off pulses, one channel per actuator pair.

    Each channel's demand :math:`d \\in [-1, 1]` (a fraction of the pair's force or
    torque) is latched at the start of each period :math:`P` and gives an on-time

    .. math::

        T_{on} = \\mathrm{round}_{\\Delta}\\left(|d| P + c\\right), \\qquad
        T_{on} = 0 \\text{ if } T_{on} < T_{min}

    rounded to whole control steps :math:`\\Delta` (``tick``). The impulse not
    delivered (rounding, or a pulse shorter than the minimum on-time :math:`T_{min}`)
    is carried, :math:`c`, into the next period, so small demands come out as
    occasional minimum pulses of the right mean instead of a dead band.

    Pulses start at the period's start; channels marked ``right_aligned`` end at
    its end instead, so two channels that share a valve overlap only when their
    duties add up to more than one.

    Parameters
    ----------
    period : float
        PWM period, s (rounded to whole ticks).
    min_on_time : float
        Shortest pulse, s.
    tick : float
        The control step at which :meth:`update` is called, s.
    channels : int
        Number of independent demands.
    right_aligned : sequence of bool
        Per channel, pulses at the end of the period.
    """

    def __init__(
        self,
        period: float,
        min_on_time: float,
        tick: float,
        channels: int = 1,
        right_aligned: Sequence[bool] = (),
    ):
        if not (tick > 0 and period >= tick * (1 - 1e-9)):
            raise ValueError(f"PWM period {period!r} s must be at least one tick ({tick!r} s)")
        if not 0 <= min_on_time < period:
            raise ValueError(f"min_on_time {min_on_time!r} s must be in [0, period)")
        if channels < 1 or len(right_aligned) > channels:
            raise ValueError(f"{channels} channels cannot have {len(right_aligned)} alignments")
        self.period = period
        self.min_on_time = min_on_time
        self.tick = tick
        self.steps = max(1, round(period / tick))
        self.channels = channels
        self.right_aligned = tuple(right_aligned) + (False,) * (channels - len(right_aligned))
        self._carry_limit = max(min_on_time, tick)
        self._start: float | None = None
        self._on = [0] * channels  # steps on, this period
        self._sign = [0] * channels
        self._carry = [0.0] * channels

    def reset(self) -> None:
        """Drop the current period and the carried impulse."""
        self._start = None
        self._on = [0] * self.channels
        self._sign = [0] * self.channels
        self._carry = [0.0] * self.channels

    def _latch(self, duty: Sequence[float]) -> None:
        for c in range(self.channels):
            d = max(-1.0, min(1.0, duty[c]))
            wanted = d * self.steps * self.tick + self._carry[c]  # s of full thrust, signed
            steps = min(self.steps, round(abs(wanted) / self.tick))
            if steps * self.tick < self.min_on_time - 1e-12:
                steps = 0
            sign = (wanted > 0) - (wanted < 0)
            carry = wanted - sign * steps * self.tick
            if steps == self.steps:  # saturated: nothing to owe
                carry = 0.0
            self._carry[c] = _clip(carry, self._carry_limit)
            self._on[c] = steps
            self._sign[c] = sign

    def update(self, now: float, duty: Sequence[float]) -> tuple[int, ...]:
        """Per channel -1, 0 or +1 for the control step starting at ``now`` (s).

        ``duty`` is read only when a period starts.
        """
        if len(duty) != self.channels:
            raise ValueError(f"expected {self.channels} demands, got {len(duty)}")
        if self._start is None:
            self._start = now
            self._latch(duty)
        j = round((now - self._start) / self.tick)
        if j >= self.steps:
            self._start += self.steps * self.tick
            j = round((now - self._start) / self.tick)
            if not 0 <= j < self.steps:  # a gap: start afresh
                self._start = now
                j = 0
            self._latch(duty)
        out = []
        for c in range(self.channels):
            n = self._on[c]
            on = j >= self.steps - n if self.right_aligned[c] else j < n
            out.append(self._sign[c] if on else 0)
        return tuple(out)


def allocate(fx: int, fy: int, torque: int) -> tuple[bool, ...]:
    """Valve states for body force signs ``fx``, ``fy`` and torque sign ``torque`` (-1, 0, +1).

    Each nonzero sign opens its pair (:data:`agents.dynamics.PAIRS`). The torque pairs
    share valves with the x pairs; when both are on, the shared valve opens once and
    both outputs come out halved (the PWM's alignment keeps that rare).
    """
    valves = [False] * len(THRUSTERS)
    for sign, axis in ((fx, "x"), (fy, "y"), (torque, "torque")):
        if sign:
            for i in PAIRS[("+" if sign > 0 else "-") + axis]:
                valves[i] = True
    return tuple(valves)


class PositionHold:
    """PD on lab-frame position with feed-forward, as a body-frame force demand.

    Holding a point (``target``), or following a :class:`~agents.guidance.Track`
    :math:`(\\mathbf{p}_r, \\mathbf{v}_r, \\mathbf{a}_r)`:

    .. math::

        \\mathbf{f}_{lab} = m\\,\\mathbf{a}_r - K_p (\\mathbf{p} - \\mathbf{p}_r)
            - K_d (\\mathbf{v} - \\mathbf{v}_r),
        \\qquad \\mathbf{f}_b = R(\\psi)^T \\mathbf{f}_{lab}

    each body component saturated at ``limit`` (N). Holding a point is the case
    :math:`\\mathbf{v}_r = \\mathbf{a}_r = 0`.

    Parameters
    ----------
    kp, kd : float
        Gains, N/m and N s/m.
    limit : float
        Force of one thruster pair, N.
    target : tuple of float
        Position to hold (x, y), m.
    mass : float
        Mass for the acceleration feed-forward, kg (0: none).
    """

    def __init__(
        self,
        kp: float,
        kd: float,
        limit: float,
        target: tuple[float, float],
        mass: float = 0.0,
    ):
        self.kp, self.kd, self.limit = kp, kd, limit
        self.target = target
        self.mass = mass

    def update(self, pose: Pose, track: Track | None = None) -> tuple[float, float]:
        """Body-frame force demand (N) for the estimated pose; ``track`` replaces the
        held target for this step."""
        if track is None:
            track = Track(*self.target)
        fx = self.mass * track.ax - self.kp * (pose.x - track.x) - self.kd * (pose.vx - track.vx)
        fy = self.mass * track.ay - self.kp * (pose.y - track.y) - self.kd * (pose.vy - track.vy)
        c = math.cos(pose.heading)
        s = math.sin(pose.heading)
        return _clip(c * fx + s * fy, self.limit), _clip(-s * fx + c * fy, self.limit)

"""Guidance: what heading each role should have at simulation time ``t``.

The leader runs the paper's reference maneuver (section 5): still for ``start``
seconds (the sync phase), then a gradual rotation to ``amplitude`` and back
within ``duration`` seconds. The profile is a raised cosine, so heading and rate
are continuous:

.. math::

    \\psi(t) = \\frac{A}{2} \\left(1 - \\cos \\frac{2\\pi (t - t_0)}{T}\\right),
    \\qquad t_0 \\le t \\le t_0 + T

The follower's reference is the heading it receives from the agent it follows: the
last sample as it is (:func:`track_heading`), or a filter over the samples on the
sender's time that predicts the followed heading and rate to now
(:class:`HeadingEstimator`).

Beyond attitude, a 3-DOF reference adds a :class:`Track`: position, velocity and
acceleration (x, y) that the GNC chain's position controller follows (the
scenarios of :mod:`agents.formation` and :mod:`agents.docking` make them).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from federation.core import paper
from federation.core.angles import wrap_angle
from federation.core.wire import PoseSample

__all__ = [
    "HeadingEstimator",
    "HeadingFilter",
    "Reference",
    "ReferenceManeuver",
    "Track",
    "track_heading",
]

Profile = Callable[[float], tuple[float, float]]
"""A maneuver on run time: ``t -> (heading rad, rate rad/s)`` (:class:`ReferenceManeuver`)."""


class Track(NamedTuple):
    """A position reference with its rates, in one frame (the common frame in guidance,
    the table frame in the GNC chain): m, m/s, m/s^2."""

    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    ax: float = 0.0
    ay: float = 0.0


class Reference(NamedTuple):
    """A 3-DOF reference: heading (rad) and rate (rad/s), and a :class:`Track` (None:
    keep the platform's own position behaviour, e.g. position hold)."""

    heading: float = 0.0
    rate: float = 0.0
    track: Track | None = None


@dataclass(frozen=True)
class ReferenceManeuver:
    start: float = paper.MANEUVER_STILL  # s of reference time held still (the sync phase)
    duration: float = paper.MANEUVER_DURATION  # s for the rotation out and back
    amplitude: float = math.radians(paper.MANEUVER_AMPLITUDE_DEG)  # rad

    def __post_init__(self) -> None:
        if not self.duration > 0:
            raise ValueError(f"maneuver duration must be positive seconds, not {self.duration!r}")

    def __call__(self, t: float) -> tuple[float, float]:
        """(heading, heading rate) at reference time ``t`` (rad, rad/s)."""
        phase = (t - self.start) / self.duration
        if not 0.0 <= phase <= 1.0:
            return 0.0, 0.0
        w = 2.0 * math.pi / self.duration
        heading = 0.5 * self.amplitude * (1.0 - math.cos(2.0 * math.pi * phase))
        rate = 0.5 * self.amplitude * w * math.sin(2.0 * math.pi * phase)
        return heading, rate


def track_heading(
    received: PoseSample | None,
    now: float | None = None,
    compensate: bool = True,
    horizon: float = 1.0,
) -> tuple[float, float]:
    """Follower reference from the last received sample (none yet: hold 0).

    With ``compensate`` (and ``now``, the present time on the *sender's* clock),
    the sample is dead-reckoned from its timestamp to ``now`` with the rate it
    carries, as DIS does, so the follower tracks where the leader is now rather
    than where it was one delay ago:

    .. math::

        \\psi_{ref} = \\psi_s + \\omega_s\\,(t_{now} - t_s), \\qquad
        0 \\le t_{now} - t_s \\le \\text{horizon}

    The extrapolation is clamped to ``horizon`` seconds so a stale sample is not
    flung far ahead.
    """
    if received is None:
        return 0.0, 0.0
    heading, rate = received.pose.heading, received.pose.omega
    if compensate and now is not None:
        age = min(max(now - received.t, 0.0), horizon)
        heading += rate * age
    return heading, rate


@dataclass(frozen=True)
class HeadingFilter:
    """The :class:`HeadingEstimator`'s noise model and limits (its defaults, in one place).

    The measurement noises are what a shared pose carries: a sender's filtered heading
    is 0.037 deg RMS off its truth and its shared rate 0.15 deg/s RMS (the simulated
    presets' Vicon and gyro, measured in rehearsal), so a received rate is mostly gyro
    noise and its heading is the better measure of how it turns.
    """

    heading_noise: float = 0.0007  # rad, 1 sigma of a shared heading
    rate_noise: float = 0.003  # rad/s, 1 sigma of a shared rate
    acceleration_noise: float = 1e-5  # rad^2/s^3: the followed agent's angular
    # acceleration beyond its maneuver's, as white noise (its spectral density)
    horizon: float = 1.0  # s: no prediction reaches further past the last sample
    restart_after: float = 1.0  # s: a sample this far from the filter's time starts it afresh
    rate_gate: float = 5.0  # sigmas: a shared rate further than this from the filter's
    # prediction is not taken (its heading is): a rate its headings do not show

    def __post_init__(self) -> None:
        for name in ("heading_noise", "rate_noise", "acceleration_noise", "horizon", "rate_gate"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"HeadingFilter.{name} must be a positive number, not {value!r}")
        if not (math.isfinite(self.restart_after) and self.restart_after > 0):
            raise ValueError(
                f"HeadingFilter.restart_after must be positive seconds, not {self.restart_after!r}"
            )


class HeadingEstimator:
    """A follower's heading reference: a Kalman filter over the received samples on the
    sender's time, the followed agent's maneuver (known to both sides) as its input:
    the maneuver as the followed platform's preset flies it, where the follower knows
    that preset (:class:`agents.flown.FollowedModel`), else the maneuver itself.

    The state is the followed heading and rate :math:`x = (\\psi, \\omega)`. Between
    two instants :math:`t_0 < t_1` of the sender's time it moves on as the maneuver
    :math:`(\\psi_m, \\omega_m)` does, beyond a constant rate:

    .. math::

        \\psi_1 = \\psi_0 + \\omega_0\\,\\Delta t
                 + \\bigl(\\psi_m(t_1) - \\psi_m(t_0) - \\omega_m(t_0)\\,\\Delta t\\bigr),
        \\qquad
        \\omega_1 = \\omega_0 + \\omega_m(t_1) - \\omega_m(t_0)

    with white acceleration noise :math:`q` (``acceleration_noise``):
    :math:`Q = q\\,[[\\Delta t^3/3, \\Delta t^2/2], [\\Delta t^2/2, \\Delta t]]`. Each sample
    newer than the filter's time is a measurement of both, noise
    :math:`R = \\mathrm{diag}(\\sigma_\\psi^2, \\sigma_\\omega^2)`. The reference is the
    state predicted to ``now`` (at most ``horizon`` past the last sample).

    Why: dead reckoning (:func:`track_heading`) gives the received rate, one delay old
    and noisy, as the rate reference, and the heading controller weighs a rate error by
    kd / kp (1.5 s on the presets). The filter's rate comes from the headings' trend and
    the maneuver's acceleration, so it neither lags by the delay nor carries the
    sender's gyro noise; a new sample moves the reference by a gain times its
    innovation, never by the whole of it.

    Safety: a sample or a ``now`` that is not finite gives a reference that is not
    finite (NaN), on which the GNC chain closes every valve (``nonfinite``), and leaves
    the filter as it was; a sample older than the filter's time (a reordered or repeated
    one) is not taken; a sample more than ``restart_after`` from the filter's time (a
    gap, a sender's restart) starts the filter afresh from it; a shared rate more than
    ``rate_gate`` sigmas from the predicted one (50 rad/s from a sender whose headings
    stand still) is left out of the update and its heading taken alone, so a rate its
    headings do not show never drags the heading reference on. Without a maneuver
    (``profile`` None: before or outside a run) the model is a constant rate.
    """

    def __init__(self, config: HeadingFilter | None = None):
        self.config = config or HeadingFilter()
        self.t: float | None = None  # sender's time of the state (the last sample taken)
        self.x = (0.0, 0.0)  # heading (rad, wrapped), rate (rad/s)
        self.p = (0.0, 0.0, 0.0)  # covariance: var heading, covariance, var rate
        self.restarts = 0  # times the filter started afresh from a sample
        self.rates_rejected = 0  # samples whose rate was not taken (rate_gate)

    def reset(self) -> None:
        """Forget every sample: the next one starts the filter."""
        self.t = None

    def reference(
        self,
        received: PoseSample | None,
        now: float | None = None,
        compensate: bool = True,
        profile: Profile | None = None,
        run_time: float | None = None,
    ) -> tuple[float, float]:
        """The heading and rate reference (rad, rad/s) at ``now`` (the sender's time).

        ``received`` is the latest sample (None yet: hold 0). Without ``compensate`` it
        is the sample as it is, as :func:`track_heading`; without ``now`` too, though the
        filter takes the sample. ``profile`` and ``run_time`` (the run time at ``now``)
        give the maneuver's motion between the sender's instants ``s``, at run time
        ``run_time + s - now``; either None: a constant rate.
        """
        if received is None:
            return 0.0, 0.0
        if not compensate:
            self.reset()
            return track_heading(received, now, compensate=False)
        sample = (received.t, received.pose.heading, received.pose.omega)
        if not all(map(math.isfinite, sample)) or (now is not None and not math.isfinite(now)):
            return math.nan, math.nan  # the chain closes every valve on it
        if run_time is not None and not math.isfinite(run_time):
            return math.nan, math.nan
        shift = None if profile is None or run_time is None or now is None else run_time - now
        self._take(received, profile, shift)
        if now is None:
            return received.pose.heading, received.pose.omega
        assert self.t is not None
        t = min(max(now, self.t), self.t + self.config.horizon)
        (heading, rate), _ = self._predict(self.x, None, self.t, t, profile, shift)
        return wrap_angle(heading), rate

    def _take(self, received: PoseSample, profile: Profile | None, shift: float | None) -> None:
        """The sample into the filter: a start, an update or nothing (not newer)."""
        t, z_heading, z_rate = received.t, received.pose.heading, received.pose.omega
        c = self.config
        if self.t is None or abs(t - self.t) > c.restart_after:
            self.t, self.x = t, (wrap_angle(z_heading), z_rate)
            self.p = (c.heading_noise**2, 0.0, c.rate_noise**2)
            self.restarts += 1
            return
        if t <= self.t:
            return
        (heading, rate), (a, b, d) = self._predict(self.x, self.p, self.t, t, profile, shift)
        r1, r2 = c.heading_noise**2, c.rate_noise**2
        v1, v2 = wrap_angle(z_heading - heading), z_rate - rate
        if v2 * v2 > c.rate_gate**2 * (d + r2):  # the heading alone: H = [1, 0]
            self.rates_rejected += 1
            s = a + r1
            k1, k2 = a / s, b / s
            heading, rate = heading + k1 * v1, rate + k2 * v1
            p = (a * r1 / s, b * r1 / s, d - b * b / s)
        else:
            det = (a + r1) * (d + r2) - b * b
            k11, k12 = (a * (d + r2) - b * b) / det, b * r1 / det
            k21, k22 = b * r2 / det, (d * (a + r1) - b * b) / det
            heading += k11 * v1 + k12 * v2
            rate += k21 * v1 + k22 * v2
            # P = (I - K) P, symmetric.
            p = ((1 - k11) * a - k12 * b, (1 - k11) * b - k12 * d, -k21 * b + (1 - k22) * d)
        self.t, self.x, self.p = t, (wrap_angle(heading), rate), p

    def _predict(
        self,
        x: tuple[float, float],
        p: tuple[float, float, float] | None,
        t0: float,
        t1: float,
        profile: Profile | None,
        shift: float | None,
    ) -> tuple[tuple[float, float], tuple[float, float, float]]:
        """State (and covariance, if given) moved from ``t0`` to ``t1`` (sender's time)."""
        dt = t1 - t0
        heading, rate = x[0] + x[1] * dt, x[1]
        if profile is not None and shift is not None:
            (h0, w0), (h1, w1) = profile(t0 + shift), profile(t1 + shift)
            heading += h1 - h0 - w0 * dt
            rate += w1 - w0
        if p is None:
            return (heading, rate), (0.0, 0.0, 0.0)
        a, b, d = p
        q = self.config.acceleration_noise
        a1 = a + 2 * b * dt + d * dt * dt + q * dt**3 / 3
        b1 = b + d * dt + q * dt * dt / 2
        d1 = d + q * dt
        return (heading, rate), (a1, b1, d1)

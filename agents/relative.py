"""Relative sensing across labs (paper section 3.2): another platform's pose as a
relative sensor on this one would see it.

The two platforms are on different tables, so no sensor can see the other; its
relative pose is made from the two inertial poses. The other's shared pose, stamped
on its clock, is first mapped to reference time with the sync estimate (the caller
does this: :meth:`federation.core.timebase.TimeBase.peer_to_sim`), then dead-reckoned
to now (:func:`dead_reckon`), and one's own estimate is subtracted, in one's body
frame:

.. math::

    \\mathbf{p}_o(t) = \\mathbf{p}_o(s) + \\mathbf{v}_o\\,(t - s), \\quad
    \\psi_o(t) = \\psi_o(s) + \\omega_o\\,(t - s)

    \\mathbf{r} = R(\\hat\\psi)^T (\\mathbf{p}_o(t) - \\hat{\\mathbf{p}}), \\quad
    \\rho = |\\mathbf{r}|, \\quad \\beta = \\operatorname{atan2}(r_y, r_x), \\quad
    \\Delta\\psi = \\psi_o(t) - \\hat\\psi

Then the noise of a chosen sensor (:class:`~schemas.scenario.RelativeSensorConfig`):
range and bearing noise growing with range,

.. math::

    \\sigma_\\rho = \\sigma_{\\rho,0} + k_\\rho\\,\\rho, \\qquad
    \\sigma_\\beta = \\sigma_{\\beta,0} + k_\\beta\\,\\rho

a field of view about the body +x axis, a maximum range, a rate and random dropouts,
all from one seeded generator. Pure: time comes in as an argument.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from federation.core.angles import wrap_angle
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import RelativeSensorConfig

__all__ = ["RelativeMeasurement", "RelativeSensor", "dead_reckon", "to_common"]


def dead_reckon(pose: Pose, age: float, horizon: float = math.inf) -> Pose:
    """``pose`` moved on by its rates over ``age`` seconds (clamped to [0, horizon])."""
    dt = min(max(age, 0.0), horizon)
    if dt == 0.0:
        return pose
    return pose._replace(
        x=pose.x + pose.vx * dt, y=pose.y + pose.vy * dt, heading=pose.heading + pose.omega * dt
    )


class RelativeMeasurement(NamedTuple):
    """What the emulated sensor gives at ``t`` (reference time, s): range (m), bearing
    from the body x axis (rad), the other's heading less one's own (rad)."""

    t: float
    range: float
    bearing: float
    heading: float

    @property
    def body(self) -> tuple[float, float]:
        """The other's position in the body frame, m."""
        return self.range * math.cos(self.bearing), self.range * math.sin(self.bearing)


def to_common(own: Pose, m: RelativeMeasurement) -> tuple[float, float, float]:
    """The other's (x, y, heading) in the common frame from one's own estimate and a
    measurement: the sensor's model inverted."""
    bx, by = m.body
    c, s = math.cos(own.heading), math.sin(own.heading)
    return own.x + c * bx - s * by, own.y + s * bx + c * by, own.heading + m.heading


class RelativeSensor:
    """The emulated relative sensor of one platform looking at one other.

    ``counters``: measurements given (``relative_given``), and none: out of the field
    of view or range (``relative_out_of_view``), a dropout (``relative_dropped``),
    nothing shared yet (``relative_no_pose``) or only too old (``relative_stale_pose``).
    ``compensate``: measure the other's shared pose dead-reckoned to now (latency
    compensation), else where it was at its stamp; either way a pose older than the
    config's ``horizon`` gives no measurement.
    """

    def __init__(self, config: RelativeSensorConfig, compensate: bool = True):
        self.config = config
        self.compensate = compensate
        self.rng = np.random.default_rng(config.seed)
        self._period = 1.0 / config.rate
        self._next: float | None = None
        self.counters = dict.fromkeys(
            (
                Count.RELATIVE_GIVEN,
                Count.RELATIVE_OUT_OF_VIEW,
                Count.RELATIVE_DROPPED,
                Count.RELATIVE_NO_POSE,
                Count.RELATIVE_STALE_POSE,
            ),
            0,
        )

    def due(self, now: float) -> bool:
        """Whether a measurement is due at ``now`` (s); schedules the next one."""
        if self._next is None:
            self._next = now
        if now + 1e-9 < self._next:
            return False
        self._next += self._period * max(1, math.floor((now - self._next) / self._period) + 1)
        return True

    def true_relative(self, now: float, other: tuple[float, Pose], own: Pose) -> Pose:
        """Range-free relative pose before noise: (x, y) in own body frame, heading
        difference; ``other`` = (its stamp on reference time, its pose)."""
        stamp, pose = other
        o = dead_reckon(pose, now - stamp, self.config.horizon) if self.compensate else pose
        dx, dy = o.x - own.x, o.y - own.y
        c, s = math.cos(own.heading), math.sin(own.heading)
        return Pose(c * dx + s * dy, -s * dx + c * dy, wrap_angle(o.heading - own.heading))

    def measure(
        self, now: float, other: tuple[float, Pose] | None, own: Pose
    ) -> RelativeMeasurement | None:
        """A measurement at ``now`` (reference time, s), or None: not due, nothing shared
        yet or nothing shared within ``horizon``, out of view or range, or dropped."""
        if not self.due(now):
            return None
        if other is None:
            self.counters[Count.RELATIVE_NO_POSE] += 1
            return None
        c = self.config
        if not -c.horizon <= now - other[0] <= c.horizon:
            # Older than the dead reckoning's horizon: the other has gone silent, and a
            # measurement made from its last pose would say it is still there (or its
            # stamp lies ahead by more: its sender's clock estimate is wrong).
            self.counters[Count.RELATIVE_STALE_POSE] += 1
            return None
        rel = self.true_relative(now, other, own)
        rng = math.hypot(rel.x, rel.y)
        bearing = math.atan2(rel.y, rel.x)
        if rng > c.max_range or abs(bearing) > math.radians(c.fov_deg) / 2:
            self.counters[Count.RELATIVE_OUT_OF_VIEW] += 1
            return None
        draw = self.rng.standard_normal(3)
        if self.rng.random() < c.dropout:
            self.counters[Count.RELATIVE_DROPPED] += 1
            return None
        sigma_r = c.range_noise + c.range_noise_per_m * rng
        sigma_b = math.radians(c.bearing_noise_deg + c.bearing_noise_per_m_deg * rng)
        self.counters[Count.RELATIVE_GIVEN] += 1
        return RelativeMeasurement(
            now,
            max(0.0, rng + sigma_r * float(draw[0])),
            wrap_angle(bearing + sigma_b * float(draw[1])),
            wrap_angle(rel.heading + math.radians(c.heading_noise_deg) * float(draw[2])),
        )

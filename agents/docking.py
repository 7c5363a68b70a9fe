"""Docking across labs: a chaser docks with a target in another lab from emulated
relative measurements alone (:mod:`agents.relative`).

The target's docking port is on its body +x axis :math:`\\mathbf{a} = (\\cos\\psi_T,
\\sin\\psi_T)`, with :math:`\\mathbf{n} = (-\\sin\\psi_T, \\cos\\psi_T)` across it. The
chaser's place relative to the target is its axial and lateral offsets

.. math::

    s = (\\mathbf{p}_C - \\mathbf{p}_T) \\cdot \\mathbf{a}, \\qquad
    l = (\\mathbf{p}_C - \\mathbf{p}_T) \\cdot \\mathbf{n}

and contact is :math:`s \\le L` (``contact_distance``, centre to centre), the chaser
facing the target (:math:`\\psi_C = \\psi_T + \\pi`). :class:`DockingGuidance` flies

1. ``approach``: a reference point moves at ``approach_speed`` from where the chaser
   is to the hold point :math:`s = L + H, l = 0`;
2. ``hold``: it stays there until the chaser has been within ``hold_tolerance`` for
   ``hold_time`` s;
3. ``final``: the point moves in along the axis at ``final_speed``; a chaser outside
   the corridor (:math:`|l| > (s - L)\\tan\\alpha` + tolerance) or without a
   measurement for ``lost_after`` s backs off to the hold point;
4. ``contact``: once its own estimate says :math:`s \\le L`, it stays there.

The chaser knows the target only through its relative sensor: each measurement with
its own navigation estimate gives the target's position and heading in the common
frame (:func:`~agents.relative.to_common`), which a constant-velocity Kalman filter
per axis (:class:`TargetFilter`) smooths and differentiates.

:func:`contact_state` scores a contact on the truth (:class:`ContactState`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from agents.guidance import Reference, Track
from agents.relative import RelativeMeasurement, RelativeSensor, to_common
from federation.core.angles import wrap_angle
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import DockingConfig, RelativeSensorConfig

__all__ = [
    "ContactState",
    "DockingGuidance",
    "TargetFilter",
    "TargetGuidance",
    "contact_state",
]

APPROACH, HOLD, FINAL, CONTACT = "approach", "hold", "final", "contact"
TARGET_JUMP = 0.1  # m a measurement may lie from the target's track before it is a jump
# (at the least: more where the sensor's noise at its range is larger, TargetFilter.jump_gate)
OVERSHOOT = 0.05  # m past contact the final reference aims at, so contact happens moving


class _Axis:
    """A constant-velocity Kalman filter of one coordinate: state (value, rate)."""

    def __init__(self, accel_sigma: float):
        self.q = accel_sigma**2
        self.x = 0.0
        self.v = 0.0
        self.p = (1.0, 0.0, 1.0)  # P11, P12, P22
        self.t: float | None = None

    def predict(self, t: float) -> None:
        if self.t is None or t <= self.t:
            return
        dt = t - self.t
        p11, p12, p22 = self.p
        q = self.q
        self.x += self.v * dt
        self.p = (
            p11 + 2 * dt * p12 + dt * dt * p22 + q * dt**4 / 4,
            p12 + dt * p22 + q * dt**3 / 2,
            p22 + q * dt * dt,
        )
        self.t = t

    def update(self, t: float, z: float, r: float) -> None:
        if self.t is None:
            self.x, self.v, self.p, self.t = z, 0.0, (r, 0.0, 0.01), t
            return
        self.predict(t)
        p11, p12, p22 = self.p
        s = p11 + r
        k1, k2 = p11 / s, p12 / s
        e = z - self.x
        self.x += k1 * e
        self.v += k2 * e
        self.p = (p11 - k1 * p11, p12 - k1 * p12, p22 - k2 * p12)

    def variance_at(self, t: float) -> float:
        """The value's variance predicted to ``t`` (the state left as it is)."""
        p11, p12, p22 = self.p
        dt = 0.0 if self.t is None else max(0.0, t - self.t)
        return p11 + 2 * dt * p12 + dt * dt * p22 + self.q * dt**4 / 4

    def at(self, t: float) -> tuple[float, float]:
        """(value, rate) extrapolated to ``t``."""
        dt = 0.0 if self.t is None else max(0.0, t - self.t)
        return self.x + self.v * dt, self.v


def position_variance(sensor: RelativeSensorConfig, m: RelativeMeasurement) -> float:
    """The variance (m^2) of a measurement's position on each axis: the larger of the
    range's and the bearing's, each growing with range."""
    sigma_r = sensor.range_noise + sensor.range_noise_per_m * m.range
    sigma_b = math.radians(sensor.bearing_noise_deg + sensor.bearing_noise_per_m_deg * m.range)
    return max(sigma_r, sigma_b * m.range, 1e-4) ** 2


class TargetFilter:
    """The target's x, y (m) and heading (rad) in the common frame, with their rates,
    from relative measurements; ``accel_sigma``: the target's unmodelled acceleration
    (m/s^2; rad/s^2 for the heading)."""

    def __init__(self, accel_sigma: float = 0.002):
        self.x, self.y, self.psi = _Axis(accel_sigma), _Axis(accel_sigma), _Axis(accel_sigma)
        self.updates = 0

    @property
    def ready(self) -> bool:
        return self.updates > 0

    def update(self, own: Pose, m: RelativeMeasurement, sensor: RelativeSensorConfig) -> None:
        x, y, psi = to_common(own, m)
        r_pos = position_variance(sensor, m)
        self.x.update(m.t, x, r_pos)
        self.y.update(m.t, y, r_pos)
        if self.psi.t is not None:  # heading continuous next to the estimate
            psi = self.psi.x + wrap_angle(psi - self.psi.x)
        self.psi.update(m.t, psi, max(math.radians(sensor.heading_noise_deg), 1e-4) ** 2)
        self.updates += 1

    def jump_gate(self, m: RelativeMeasurement, sensor: RelativeSensorConfig) -> float:
        """How far (m) measurement ``m`` may lie from the target's predicted position
        before it is a jump: ``TARGET_JUMP``, or five standard deviations of the
        difference where the sensor's noise (growing with range) and the estimate's own
        spread make more (at 3.9 m a fixed 0.1 m is 3 sigma: noise alone would be
        taken for a jump)."""
        spread = position_variance(sensor, m) + self.x.variance_at(m.t) + self.y.variance_at(m.t)
        return max(TARGET_JUMP, 5.0 * math.sqrt(spread))

    def at(self, t: float) -> Pose:
        (x, vx), (y, vy), (psi, w) = self.x.at(t), self.y.at(t), self.psi.at(t)
        return Pose(x, y, psi, vx, vy, w)


class ContactState(NamedTuple):
    """The chaser relative to the target's port: axial and lateral offsets (m), heading
    error from facing the target (rad, wrapped), closing speed (m/s, positive closing)."""

    axial: float
    lateral: float
    heading_error: float
    closing_speed: float


def contact_state(chaser: Pose, target: Pose) -> ContactState:
    """Where the chaser is relative to the target's docking axis (both common frame)."""
    a = (math.cos(target.heading), math.sin(target.heading))
    n = (-a[1], a[0])
    dx, dy = chaser.x - target.x, chaser.y - target.y
    dvx, dvy = chaser.vx - target.vx, chaser.vy - target.vy
    return ContactState(
        dx * a[0] + dy * a[1],
        dx * n[0] + dy * n[1],
        wrap_angle(chaser.heading - target.heading - math.pi),
        -(dvx * a[0] + dvy * a[1]),
    )


class DockingGuidance:
    """The chaser's reference from its relative measurements and own estimate.

    ``phase`` is one of ``approach``, ``hold``, ``final``, ``contact``; ``counters``:
    ``backoffs_corridor``, ``backoffs_lost``; ``events``: (reference time, phase) at
    each change.
    """

    def __init__(
        self, config: DockingConfig, sensor: RelativeSensorConfig, compensate: bool = True
    ):
        self.config = config
        self.sensor_config = sensor
        self.sensor = RelativeSensor(sensor, compensate)
        self.target = TargetFilter()
        self.phase = APPROACH
        self.events: list[tuple[float, str]] = []
        self.counters = {Count.BACKOFFS_CORRIDOR: 0, Count.BACKOFFS_LOST: 0, Count.TARGET_JUMPS: 0}
        self._carrot: tuple[float, float] | None = None  # (s, l) of the reference point
        self._t: float | None = None
        self._settled_since: float | None = None
        self._last_measurement: float | None = None
        self._heading: float | None = None
        self.last_measurement: RelativeMeasurement | None = None

    def new_run(self) -> None:
        """A new run: phase, reference point and target estimate begin afresh (a chaser
        left at contact would otherwise be sent straight to the contact point, and a
        target filter would carry the last run's target). Counters, and the sensor with
        its own, are kept."""
        self.target = TargetFilter()
        self.phase = APPROACH
        self._carrot = None
        self._t = None
        self._settled_since = None
        self._last_measurement = None
        self._heading = None
        self.last_measurement = None

    def _go(self, t: float, phase: str) -> None:
        if phase != self.phase:
            self.phase = phase
            self.events.append((t, phase))

    def reference(
        self,
        t: float | None,
        run_time: float | None,
        target_shared: tuple[float, Pose] | None,
        own: Pose,
        frozen: bool = False,
    ) -> Reference:
        """The reference at reference time ``t`` (s); ``target_shared`` = the target's
        shared pose and its stamp on reference time (what the sensor is emulated from).
        ``frozen``: the run is paused: the reference point and the phase stay where
        they are (the target is still tracked), and the track asks no motion."""
        if self._heading is None:
            self._heading = own.heading
        if t is None or run_time is None:
            return Reference(self._heading, 0.0, None)
        m = self.sensor.measure(t, target_shared, own)
        if m is not None and self.target.ready:
            x, y, _ = to_common(own, m)
            pred = self.target.at(m.t)
            if math.hypot(x - pred.x, y - pred.y) > self.target.jump_gate(m, self.sensor_config):
                # The target is not where it was: no approach goes on toward a point
                # that moved under it. Begin again from where the chaser is.
                self.counters[Count.TARGET_JUMPS] += 1
                self.target = TargetFilter()
                self._carrot = None
                self._settled_since = None
                if self.phase != APPROACH:
                    self._go(t, APPROACH)
        if m is not None:
            self.target.update(own, m, self.sensor_config)
            self._last_measurement = t
            self.last_measurement = m
        if not self.target.ready:
            return Reference(self._heading, 0.0, None)
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        last = self._last_measurement
        if last is not None and t - last > self.config.lost_after:
            # Lost: where it was last seen, not where its last rates would carry it (a
            # target that stops out of view would be chased at its old drift for minutes).
            tgt = self.target.at(last)._replace(vx=0.0, vy=0.0, omega=0.0)
        else:
            tgt = self.target.at(t)
        here = contact_state(own, tgt)
        if frozen and self._carrot is not None:
            return self._track(tgt, still=True)
        self._advance(t, dt, here)
        return self._track(tgt)

    def _advance(self, t: float, dt: float, here: ContactState) -> None:
        """Move the reference point and the phase on by ``dt`` s, the chaser at ``here``."""
        c = self.config
        if self._carrot is None:
            self._carrot = (here.axial, here.lateral)
            self.events.append((t, self.phase))
        lost = self._last_measurement is None or t - self._last_measurement > c.lost_after
        if self.phase == FINAL:
            self._final(t, dt, here, lost)  # a back-off flies the approach in this step
        if self.phase == APPROACH:
            self._approach(t, dt)
        elif self.phase == HOLD:
            self._hold(t, here, lost)

    @property
    def _hold_axial(self) -> float:
        """s (m) of the hold point."""
        return self.config.contact_distance + self.config.hold_distance

    def _approach(self, t: float, dt: float) -> None:
        """The point moves at ``approach_speed`` to the hold point; there, hold."""
        assert self._carrot is not None
        s, lat = self._carrot
        hold_s = self._hold_axial
        ds, dl = hold_s - s, -lat
        dist = math.hypot(ds, dl)
        step = self.config.approach_speed * dt
        if dist <= step:
            self._carrot = (hold_s, 0.0)
            self._go(t, HOLD)
        else:
            self._carrot = (s + ds * step / dist, lat + dl * step / dist)

    def _hold(self, t: float, here: ContactState, lost: bool) -> None:
        """The point stays; the final approach begins once the chaser has been within
        ``hold_tolerance`` of it, nearly still and measuring, for ``hold_time`` s."""
        c = self.config
        err = math.hypot(here.axial - self._hold_axial, here.lateral)
        if lost or err > c.hold_tolerance or abs(here.closing_speed) > 0.005:
            self._settled_since = None
        elif self._settled_since is None:
            self._settled_since = t
        elif t - self._settled_since >= c.hold_time:
            self._go(t, FINAL)

    def _final(self, t: float, dt: float, here: ContactState, lost: bool) -> None:
        """The point moves in along the axis at ``final_speed``; contact once the chaser
        is within ``contact_distance``; back to the approach (to the hold point) when the
        chaser leaves the corridor or its measurements stop."""
        c = self.config
        assert self._carrot is not None
        s, _ = self._carrot
        corridor = max(0.0, here.axial - c.contact_distance) * math.tan(
            math.radians(c.corridor_deg)
        )
        if lost or abs(here.lateral) > corridor + c.hold_tolerance:
            self.counters[Count.BACKOFFS_LOST if lost else Count.BACKOFFS_CORRIDOR] += 1
            self._settled_since = None
            self._go(t, APPROACH)
        elif here.axial <= c.contact_distance:
            self._carrot = (c.contact_distance, 0.0)
            self._go(t, CONTACT)
        else:
            self._carrot = (max(c.contact_distance - OVERSHOOT, s - c.final_speed * dt), 0.0)

    def _track(self, tgt: Pose, still: bool = False) -> Reference:
        c = self.config
        assert self._carrot is not None
        s, lat = self._carrot
        a = (math.cos(tgt.heading), math.sin(tgt.heading))
        n = (-a[1], a[0])
        ds = -c.final_speed if self.phase == FINAL and s > c.contact_distance - OVERSHOOT else 0.0
        w = tgt.omega
        if still:  # paused: the point where it is, no rates
            point = Track(tgt.x + s * a[0] + lat * n[0], tgt.y + s * a[1] + lat * n[1], 0.0, 0.0)
            return Reference(tgt.heading + math.pi, 0.0, point)
        # d/dt (p_T + s a + l n) = v_T + ds a + w (s n - l a)
        vx = tgt.vx + ds * a[0] + w * (s * n[0] - lat * a[0])
        vy = tgt.vy + ds * a[1] + w * (s * n[1] - lat * a[1])
        track = Track(tgt.x + s * a[0] + lat * n[0], tgt.y + s * a[1] + lat * n[1], vx, vy)
        return Reference(tgt.heading + math.pi, w, track)


class TargetGuidance:
    """The target: still, rotating (``target_rate_deg``) or drifting (``target_drift``)
    from where it is when the run starts."""

    def __init__(self, config: DockingConfig):
        self.rate = math.radians(config.target_rate_deg)
        self.drift = config.target_drift
        self._start: Pose | None = None
        self._heading: float | None = None

    def new_run(self) -> None:
        """A new run starts from where the target is then, not where the last one did."""
        self._start = None
        self._heading = None

    def reference(self, run_time: float | None, own: Pose, frozen: bool = False) -> Reference:
        """The target's reference at ``run_time`` (None before the start: keep the
        heading it had first, no track); ``frozen``: paused, so no rates."""
        if self._heading is None:
            self._heading = own.heading
        if run_time is None:
            return Reference(self._heading, 0.0)
        if self._start is None:
            self._start = own._replace(heading=self._heading)
        p, t = self._start, max(0.0, run_time)
        vx, vy, rate = (0.0, 0.0, 0.0) if frozen else (*self.drift, self.rate)
        track = Track(p.x + self.drift[0] * t, p.y + self.drift[1] * t, vx, vy)
        return Reference(p.heading + self.rate * t, rate, track)

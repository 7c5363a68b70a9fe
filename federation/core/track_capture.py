"""Capturing a scenario's position reference at bounded speed and acceleration, and
the docking keep-out a rejoining chaser is judged by, free of I/O.

A platform rejoining a formation or a docking (:mod:`federation.core.rejoin`) is
wherever its earlier run, and the time its agent was away, left it: handed to its
position controller as is, the scenario's track (position, velocity, acceleration) is a
step. :class:`TrackCapture` gives instead a reference :math:`(\\mathbf{p}_c,
\\mathbf{v}_c, \\mathbf{a}_c)` that starts at the platform's position and velocity and
reaches the scenario's :math:`(\\mathbf{p}, \\mathbf{v}, \\mathbf{a})` as one 2-D vector
(the same in any frame: a lab's table is the common frame turned and moved), with

.. math::

    |\\mathbf{v}_c| \\le v_{max}, \\qquad
    |\\mathbf{v}_c(k+1) - \\mathbf{v}_c(k)| \\le a_{max}\\,\\Delta t, \\qquad
    \\mathbf{a}_c = \\frac{\\mathbf{v}_c(k+1) - \\mathbf{v}_c(k)}{\\Delta t}

(:class:`TrackLimits`, from the platform preset: :math:`a_{max}` its operated thrust
over its mass, the deceleration its area keeps in reserve too, and :math:`v_{max}`
the fastest a scenario path may move). The velocity asked follows the braking curve
of the position error :math:`\\mathbf{e} = \\mathbf{p} - \\mathbf{p}_c`,

.. math::

    \\mathbf{v}_w = \\mathbf{v} + k\\,\\sqrt{2 b\\,|\\mathbf{e}|}\\,
        \\frac{\\mathbf{e}}{|\\mathbf{e}|}, \\qquad b = \\beta\\,a_{max}

with :math:`\\beta` = :data:`BRAKE_SHARE` and :math:`k \\le 1` the largest that keeps
:math:`|\\mathbf{v}_w| \\le v_{max}` (the target's own velocity kept, only the closing
term cut). Braking at :math:`b` leaves :math:`(1 - \\beta)\\,a_{max}` for the target's
own acceleration, so a target that moves within :math:`|\\mathbf{v}| < v_{max}` and
:math:`|\\mathbf{a}| \\le (1 - \\beta)\\,a_{max}` is met without overshoot. Once within
:data:`POSITION_TOL` and :data:`VELOCITY_TOL` of it, it is captured: the scenario's
track passes through unchanged from the next step on. Position and velocity never
step; the acceleration asked is the feed-forward and changes by at most
:math:`2 a_{max}` at once.

Safety: a target, a ``dt`` or a starting state that is not finite gives a reference
that is not finite (NaN) and leaves the capture as it was; on it the GNC chain closes
every valve (``nonfinite``), as on the heading capture's
(:class:`federation.core.capture.Capture`).

The docking keep-out (:func:`docking_keep_out`): the chaser docks on the target's port
at ``contact_distance`` (centre to centre) after settling at the hold point
``hold_distance`` beyond it; nearer the target than ``contact_distance`` is a
collision. A chaser rejoins only before its final approach: at least the hold point's
distance from the target's centre, and with its way to the hold point (a fresh
approach from where it is, :class:`agents.docking.DockingGuidance`, and the braking of
its present velocity at the capture's deceleration before it) outside the keep-out.
Anything nearer, or a way that would cross the target, is refused with why: its
earlier run may have been in the final approach or at contact, which a new process
cannot take up without the hold's settling, and a capture from there would pass
within the target's body.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol

__all__ = [
    "BRAKE_SHARE",
    "POSITION_TOL",
    "VELOCITY_TOL",
    "Setpoint",
    "TrackCapture",
    "TrackLike",
    "TrackLimits",
    "docking_keep_out",
]

BRAKE_SHARE = 0.5
"""Share of ``max_accel`` the braking curve uses (the rest: the target's own
acceleration)."""
POSITION_TOL = 5e-3
"""m: within this of the scenario's position (and :data:`VELOCITY_TOL` of its velocity),
captured. The position controller's answer to either is under 0.05 N (its gains, 2.5 N/m
and 9 N s/m on the presets), an eighth of one thruster pair."""
VELOCITY_TOL = 5e-3
"""m/s: see :data:`POSITION_TOL`."""


class TrackLike(Protocol):
    """What the capture reads of a position reference (``agents.guidance.Track`` is one):
    m, m/s, m/s^2."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def vx(self) -> float: ...
    @property
    def vy(self) -> float: ...
    @property
    def ax(self) -> float: ...
    @property
    def ay(self) -> float: ...


class Setpoint(NamedTuple):
    """A position reference with its rates, in the target's frame: m, m/s, m/s^2 (the
    fields of ``agents.guidance.Track``, in its order)."""

    x: float
    y: float
    vx: float
    vy: float
    ax: float = 0.0
    ay: float = 0.0


NOT_FINITE = Setpoint(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan)
"""The reference given for a non-finite input: the GNC chain closes every valve on it."""


@dataclass(frozen=True)
class TrackLimits:
    """What a position reference may ask of the platform: ``max_speed`` (m/s) and
    ``max_accel`` (m/s^2)."""

    max_speed: float
    max_accel: float

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_accel"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"TrackLimits.{name} must be a positive number, not {value!r}")


def _finite(*values: float) -> bool:
    return all(map(math.isfinite, values))


class TrackCapture:
    """The position reference a joining platform follows, from its position ``x``, ``y``
    (m) and velocity ``vx``, ``vy`` (m/s) onto the scenario's track, within ``limits``
    (see the module)."""

    def __init__(self, x: float, y: float, vx: float, vy: float, limits: TrackLimits):
        self.limits = limits
        speed = math.hypot(vx, vy)
        scale = limits.max_speed / speed if speed > limits.max_speed else 1.0
        self.x, self.y = x, y
        self.vx, self.vy = vx * scale, vy * scale  # a speed beyond the limit clipped first
        self.captured = False

    def _closing(self, target: TrackLike) -> tuple[float, float]:
        """The velocity asked: the target's, plus the braking curve's closing term cut
        to keep within ``max_speed``."""
        lim = self.limits
        ex, ey = target.x - self.x, target.y - self.y
        d = math.hypot(ex, ey)
        tvx, tvy = target.vx, target.vy
        tspeed = math.hypot(tvx, tvy)
        if tspeed > lim.max_speed:  # a target faster than the platform: its direction
            return tvx * lim.max_speed / tspeed, tvy * lim.max_speed / tspeed
        if d == 0.0:
            return tvx, tvy
        ux, uy = ex / d, ey / d
        along = tvx * ux + tvy * uy
        # The largest closing speed t >= 0 with |v + t u| <= max_speed.
        room = -along + math.sqrt(max(0.0, along * along - tspeed**2 + lim.max_speed**2))
        closing = min(math.sqrt(2.0 * BRAKE_SHARE * lim.max_accel * d), room)
        return tvx + closing * ux, tvy + closing * uy

    def step(self, target: TrackLike, dt: float) -> Setpoint:
        """The reference ``dt`` s (>= 0) after the last one, toward the scenario's
        ``target`` now; NaN everywhere for a non-finite input (see the module)."""
        if self.captured:
            return Setpoint(target.x, target.y, target.vx, target.vy, target.ax, target.ay)
        fields = (target.x, target.y, target.vx, target.vy, target.ax, target.ay)
        if not (_finite(*fields, dt, self.x, self.y, self.vx, self.vy) and dt >= 0.0):
            return NOT_FINITE
        wx, wy = self._closing(target)
        dvx, dvy = wx - self.vx, wy - self.vy
        dv, most = math.hypot(dvx, dvy), self.limits.max_accel * dt
        if dv > most:
            dvx, dvy = dvx * most / dv, dvy * most / dv
        ax, ay = (dvx / dt, dvy / dt) if dt > 0.0 else (0.0, 0.0)
        self.vx, self.vy = self.vx + dvx, self.vy + dvy
        self.x, self.y = self.x + self.vx * dt, self.y + self.vy * dt
        off = math.hypot(target.x + target.vx * dt - self.x, target.y + target.vy * dt - self.y)
        if off <= POSITION_TOL and math.hypot(target.vx - self.vx, target.vy - self.vy) <= (
            VELOCITY_TOL
        ):
            self.captured = True
        return Setpoint(self.x, self.y, self.vx, self.vy, ax, ay)


def _distance_to_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Distance (m) from point p to the segment a-b."""
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((px - ax) * dx + (py - ay) * dy) / length2))
    return math.hypot(px - ax - t * dx, py - ay - t * dy)


def docking_keep_out(
    chaser: tuple[float, float, float, float],
    target: tuple[float, float, float],
    contact_distance: float,
    hold_distance: float,
    brake: float,
) -> str | None:
    """Why a docking chaser may not rejoin now (None: it may), see the module.

    ``chaser`` is its position and velocity ``(x, y, vx, vy)`` (m, m/s), ``target`` the
    target's position and heading ``(x, y, heading)`` (m, rad), both in the common frame;
    ``brake`` the deceleration its capture asks at most (m/s^2). Non-finite input is
    refused (nothing can be judged by it).
    """
    x, y, vx, vy = chaser
    tx, ty, heading = target
    if not (_finite(*chaser, *target, contact_distance, hold_distance, brake) and brake > 0):
        return "docking: the chaser's or the target's pose is not finite: no rejoin"
    hold_r = contact_distance + hold_distance
    here = math.hypot(x - tx, y - ty)
    if here < hold_r:
        return (
            f"docking: the chaser is {here:.2f} m from the target, inside the hold point's "
            f"{hold_r:.2f} m (its final approach): no rejoin"
        )
    speed = math.hypot(vx, vy)
    stop = speed / (2.0 * brake)  # the braking distance over the speed, s
    sx, sy = x + vx * stop, y + vy * stop  # where the capture has it stopped
    hx, hy = tx + hold_r * math.cos(heading), ty + hold_r * math.sin(heading)
    nearest = min(
        _distance_to_segment(tx, ty, x, y, sx, sy), _distance_to_segment(tx, ty, sx, sy, hx, hy)
    )
    if nearest < contact_distance:
        return (
            f"docking: the chaser's way to the hold point passes {nearest:.2f} m from the "
            f"target, inside its {contact_distance:.2f} m keep-out: no rejoin"
        )
    return None

"""Capturing a scenario's heading reference at bounded rate and acceleration, free of
I/O: a platform joining a run under way starts where it is, not where the scenario is.

A rejoined follower's reference (the leader's heading on reference time) may be far
from its own heading and turning. Handed to its controller as is, it is a step. The
capture filter gives instead a reference :math:`(\\psi_c, \\omega_c)` that starts at
the platform's heading and rate and reaches the scenario's :math:`(\\psi, \\omega)`
with

.. math::

    |\\omega_c| \\le \\omega_{max}, \\qquad
    |\\omega_c(k+1) - \\omega_c(k)| \\le \\alpha_{max} \\, \\Delta t

(the platform preset's ``max_rate`` and its operated torque over its inertia). The rate
asked follows the braking curve :math:`\\omega_c = \\omega + \\mathrm{sign}(e)
\\sqrt{2 \\alpha_{max} |e|}` of the heading error :math:`e = \\psi - \\psi_c` (wrapped),
so the error closes without overshoot once the limits allow. Once within
:data:`HEADING_TOL` and :data:`RATE_TOL` of the scenario, and within one step's change
of the scenario's rate one step on (the scenario's own acceleration, from its last two
rates, counted: a sinusoid turning at the limit asked 1.7 times it on the hand-over's
step when it was not), it is captured: the scenario's reference passes through unchanged
from then on.

Safety: a target, a rate, a ``dt`` or a starting state that is not finite gives a
reference that is not finite (NaN) and leaves the capture as it was; on it the GNC chain
closes every valve (``nonfinite``). The limits alone would not: Python's ``min`` and
``max`` pass a NaN error through as the largest rate allowed, a finite reference that
turns the platform at ``max_rate`` toward nothing.

A position reference (formation, docking) has its own capture,
:class:`federation.core.track_capture.TrackCapture`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from federation.core.angles import wrap_angle

__all__ = ["HEADING_TOL", "RATE_TOL", "Capture", "Limits"]

HEADING_TOL = 2e-3
"""rad: within this of the scenario's heading (and :data:`RATE_TOL` of its rate), captured."""
RATE_TOL = 2e-3
"""rad/s: see :data:`HEADING_TOL`."""


@dataclass(frozen=True)
class Limits:
    """What a reference may ask of the platform: ``max_rate`` (rad/s) and ``max_accel``
    (rad/s^2)."""

    max_rate: float
    max_accel: float

    def __post_init__(self) -> None:
        if not (self.max_rate > 0 and self.max_accel > 0):
            raise ValueError(f"limits must be positive: {self}")


class Capture:
    """The reference a joining platform follows, from ``heading`` (rad) and ``rate``
    (rad/s) onto the scenario's, within ``limits``."""

    def __init__(self, heading: float, rate: float, limits: Limits):
        self.limits = limits
        self.heading = wrap_angle(heading)
        self.rate = max(-limits.max_rate, min(limits.max_rate, rate))
        self.captured = False
        self._last_target_rate: float | None = None  # the scenario's rate a step ago

    def step(self, target: float, target_rate: float, dt: float) -> tuple[float, float]:
        """The reference ``dt`` s (>= 0) after the last one, toward the scenario's
        ``target`` heading (rad) and ``target_rate`` (rad/s) now; NaN for a non-finite
        input (see the module)."""
        if self.captured:
            return target, target_rate
        if not (
            all(map(math.isfinite, (target, target_rate, dt, self.heading, self.rate)))
            and dt >= 0.0
        ):
            return math.nan, math.nan  # the chain closes every valve on it
        lim = self.limits
        error = wrap_angle(target - self.heading)
        brake = math.copysign(math.sqrt(2.0 * lim.max_accel * abs(error)), error)
        wanted = max(-lim.max_rate, min(lim.max_rate, target_rate + brake))
        dv = lim.max_accel * dt
        self.rate = max(self.rate - dv, min(self.rate + dv, wanted))
        self.heading = wrap_angle(self.heading + self.rate * dt)
        left = wrap_angle(target + target_rate * dt - self.heading)
        # Captured once the scenario's rate a step on (its acceleration from its last
        # two rates) is within one step's change (and RATE_TOL): the step that hands over
        # to it then asks no more than the limits allow.
        last, self._last_target_rate = self._last_target_rate, target_rate
        if last is not None and abs(left) <= HEADING_TOL:
            ahead = 2.0 * target_rate - last
            if max(abs(target_rate - self.rate), abs(ahead - self.rate)) <= min(RATE_TOL, dv):
                self.captured = True
        return self.heading, self.rate

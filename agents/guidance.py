"""Guidance: what heading each role should have at simulation time ``t``.

The leader runs the paper's reference maneuver (section 5): still for ``start``
seconds (the sync phase), then a gradual rotation to ``amplitude`` and back
within ``duration`` seconds. The profile is a raised cosine, so heading and rate
are continuous:

.. math::

    \\psi(t) = \\frac{A}{2} \\left(1 - \\cos \\frac{2\\pi (t - t_0)}{T}\\right),
    \\qquad t_0 \\le t \\le t_0 + T

The follower's reference is the heading it last received from the agent it follows.

Beyond attitude, a 3-DOF reference adds a :class:`Track`: position, velocity and
acceleration (x, y) that the GNC chain's position controller follows (the
scenarios of :mod:`agents.formation` and :mod:`agents.docking` make them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from federation.core import paper
from federation.core.wire import PoseSample

__all__ = ["Reference", "ReferenceManeuver", "Track", "track_heading"]


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

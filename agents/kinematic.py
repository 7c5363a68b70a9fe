"""Kinematic platform: the pose is the commanded trajectory.

A pose source with no inertia and no thrusters: it follows the commanded
heading exactly at a fixed position. Useful for protocol tests and for agents
that only relay a trajectory; the simulated platforms (:mod:`agents.simulated`)
fly real dynamics.
"""

from __future__ import annotations

from agents.guidance import Track
from agents.interface import WithoutChain
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["KinematicPlatform"]


class KinematicPlatform(WithoutChain):
    """``rate``: steps per second; with no dynamics, the pose rate is enough. Its pose is
    the command, so it is always a fix (:class:`~agents.interface.WithoutChain`)."""

    kind = "kinematic"
    """Its name in an agent's ``platform`` spec (:data:`schemas.platform.PLATFORMS`)."""
    argument = None
    hardware = False

    config: PlatformConfig | None = None
    """No physical description: nothing to analyse."""

    @classmethod
    def check_spec(cls, argument: str | None) -> None:
        """``kinematic`` takes no argument."""
        if argument is not None:
            raise ValueError(f"the kinematic platform takes no argument, not {argument!r}")

    @classmethod
    def from_spec(
        cls, argument: str | None, *, seed: int, rate: float, preset: str | None
    ) -> KinematicPlatform:
        """A kinematic platform stepping at ``rate`` Hz (no noise: ``seed`` unused)."""
        return cls(rate=rate)

    def __init__(self, x: float = 0.0, y: float = 0.0, rate: float = 20.0):
        if not rate > 0:
            raise ValueError(f"rate must be positive Hz, not {rate!r}")
        self.rate = rate
        self.pose = Pose(x=x, y=y)
        self.held = False

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """The pose is the reference: heading and rate, and the track's position and
        velocity if one is given (else the position stays)."""
        p = self.pose  # built directly: NamedTuple._replace costs several times more
        if self.held:
            self.pose = Pose(p.x, p.y, p.heading, 0.0, 0.0, 0.0)
        elif track is None:
            self.pose = Pose(p.x, p.y, heading_ref, p.vx, p.vy, rate_ref)
        else:
            self.pose = Pose(track.x, track.y, heading_ref, track.vx, track.vy, rate_ref)
        return self.pose

    def hold(self) -> None:
        self.held = True

    def release(self) -> None:
        self.held = False

    def close(self) -> None:
        """Nothing to release."""
        self.held = True

"""Kinematic platform: the pose is the commanded trajectory.

The stand-in pose source until simulated dynamics exist: it follows the
commanded heading exactly (no inertia, no thrusters) at a fixed position.
"""

from __future__ import annotations

from typing import Protocol

from federation.wire import Pose

__all__ = ["KinematicPlatform", "Platform"]


class Platform(Protocol):
    """A pose source: advanced to time ``t`` with a heading command, returns its pose."""

    def step(self, t: float, heading_ref: float, rate_ref: float) -> Pose: ...


class KinematicPlatform:
    def __init__(self, x: float = 0.0, y: float = 0.0):
        self.pose = Pose(x=x, y=y)

    def step(self, t: float, heading_ref: float, rate_ref: float) -> Pose:
        self.pose = self.pose._replace(heading=heading_ref, omega=rate_ref)
        return self.pose

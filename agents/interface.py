"""What the agent runtime drives: the :class:`Platform` protocol and :class:`PlatformError`.

Rule: this module imports no platform, so every platform module (kinematic,
simulated, serial) and :mod:`agents.platform`, which builds them, can import it
without an import cycle. Import both names from :mod:`agents.platform`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from agents.guidance import Track
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["Platform", "PlatformError"]


class PlatformError(RuntimeError):
    """The platform cannot be driven (a serial port vanished, say); valves are closed."""


@runtime_checkable
class Platform(Protocol):
    """A pose source driven by a heading command (and optionally a position track).

    The agent calls :meth:`step` :attr:`rate` times a second with its clock's time
    and the guidance's heading and rate references; the returned pose is what it
    publishes (for a simulated or real platform: its navigation estimate).
    :meth:`hold` closes every valve until :meth:`release` (safe hold); :meth:`close`
    closes them for good and releases what the platform holds (a serial port).
    """

    @property
    def rate(self) -> float:
        """Steps per second the platform expects, Hz."""
        ...

    @property
    def config(self) -> PlatformConfig | None:
        """The physical description (mass, inertia, gains); None for a kinematic one."""
        ...

    @property
    def held(self) -> bool:
        """Whether :meth:`hold` is in force."""
        ...

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """Advance to ``t`` (s) towards ``heading_ref`` (rad) at ``rate_ref`` (rad/s) and,
        if given, along ``track`` (a position reference with its rates, 3-DOF)."""
        ...

    def hold(self) -> None:
        """Close every valve now and keep them closed until :meth:`release`."""
        ...

    def release(self) -> None:
        """End :meth:`hold`: control resumes from a clean start."""
        ...

    def close(self) -> None:
        """Every valve closed, resources released; idempotent."""
        ...

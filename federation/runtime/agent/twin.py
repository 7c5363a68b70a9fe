"""The stand-in's platform: a simulated twin of the leader's preset that exists only while
the stand-in holds the leader's role.

Until :meth:`Twin.start_from` there is no plant: no valve, no pose (``has_fix`` is
False, so the agent publishes none) and nothing that could move. Started, it is a
:class:`~agents.simulated.SimulatedPlatform` of the preset whose plant begins at the
pose and velocity given (the leader's last shared ones) and whose navigation filter
learns them from its first fixes; :meth:`Twin.stop` (the role released) drops it
again. Hold and release pass through to it, and are kept for the next one.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from agents.control import HeadingPid
from agents.guidance import Track
from agents.interface import ClosedCause
from agents.simulated import SimulatedPlatform
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["Twin"]

_CLOSED = (False,) * 8


class Twin:
    """A twin of ``config`` (the leader's preset) with sensor noise of ``seed``."""

    kind = "twin"
    hardware = False
    valves_confirmed: bool | None = None

    def __init__(self, config: PlatformConfig, seed: int = 0):
        self.config: PlatformConfig | None = config
        self._preset = config
        self.rate: float = config.control.rate
        self.seed = seed
        self.inner: SimulatedPlatform | None = None
        self._held = True
        self._idle = Pose()

    # -- the twin's life -------------------------------------------------------------
    def start_from(self, pose: Pose) -> None:
        """A new plant at ``pose`` (position, heading and their rates), held or released
        as the twin is."""
        inner = SimulatedPlatform(self._preset, self.seed, x=pose.x, y=pose.y, heading=pose.heading)
        inner.plant.state = np.array(list(pose), dtype=np.float64)
        if self._held:
            inner.hold()
        else:
            inner.release()
        self.inner = inner

    def stop(self) -> None:
        """No plant from now on: every valve closed, no pose."""
        inner, self.inner = self.inner, None
        if inner is not None:
            inner.close()

    # -- the Platform protocol -------------------------------------------------------
    @property
    def held(self) -> bool:
        return self._held

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        inner = self.inner
        if inner is None:
            return self._idle
        return inner.step(t, heading_ref, rate_ref, track)

    def hold(self) -> None:
        self._held = True
        if self.inner is not None:
            self.inner.hold()

    def release(self) -> None:
        self._held = False
        if self.inner is not None:
            self.inner.release()

    def close(self) -> None:
        self._held = True
        self.stop()

    @property
    def has_fix(self) -> bool:
        return self.inner is not None and self.inner.has_fix

    @property
    def restarted(self) -> bool:
        return self.inner is not None and self.inner.restarted

    def acknowledge_restart(self) -> None:
        if self.inner is not None:
            self.inner.acknowledge_restart()

    @property
    def cause(self) -> ClosedCause | None:
        return None if self.inner is None else self.inner.cause

    @property
    def acquiring(self) -> tuple[int, int] | None:
        return None if self.inner is None else self.inner.acquiring

    @property
    def last_rejection(self) -> str | None:
        return None if self.inner is None else self.inner.last_rejection

    @property
    def valves(self) -> tuple[bool, ...]:
        return _CLOSED if self.inner is None else self.inner.valves

    @property
    def truth(self) -> Pose | None:
        return None if self.inner is None else self.inner.truth

    @property
    def counters(self) -> Mapping[Count, int]:
        return {} if self.inner is None else self.inner.counters

    @property
    def heading_pid(self) -> HeadingPid | None:
        return None if self.inner is None else self.inner.heading_pid

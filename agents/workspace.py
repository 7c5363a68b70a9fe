"""Frames and workspaces: each lab's table in the common frame, and the area a
platform may use on it.

A lab's table frame sits in the federation's common frame by a rotation
:math:`\\theta` and an origin :math:`\\mathbf{o}` (:class:`Frame`):

.. math::

    \\mathbf{p}_c = R(\\theta)\\,\\mathbf{p}_t + \\mathbf{o}, \\qquad
    \\mathbf{v}_c = R(\\theta)\\,\\mathbf{v}_t, \\qquad \\psi_c = \\psi_t + \\theta

Poses on the wire and guidance are in the common frame; the GNC chain and its
metrology in the table frame. :class:`FramedPlatform` wraps a platform so that the
agent sees only the common frame, and keeps the workspace's two rules:

- a position reference outside the usable :class:`Area` is clamped onto it and
  counted (``workspace_clamped``): guidance never commands a point outside;
- a platform whose estimate leaves the area goes to safe hold (every valve closed,
  ``workspace_holds``), and stays held until :meth:`FramedPlatform.clear_workspace_hold`
  (an operator's decision; a link resuming does not release it).

Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from agents.control import HeadingPid
from agents.guidance import Track
from agents.interface import ClosedCause, Platform, WithChain
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig
from schemas.scenario import LabFrame

if TYPE_CHECKING:
    from agents.gnc import GncChain

__all__ = ["Area", "Frame", "FramedPlatform"]


@dataclass(frozen=True)
class Frame:
    """A table frame in the common frame: origin (m) and rotation (rad)."""

    origin: tuple[float, float] = (0.0, 0.0)
    rotation: float = 0.0

    @classmethod
    def from_config(cls, frame: LabFrame) -> Frame:
        return cls(frame.origin, math.radians(frame.rotation_deg))

    def _rot(self, x: float, y: float, sign: float) -> tuple[float, float]:
        c, s = math.cos(self.rotation), sign * math.sin(self.rotation)
        return c * x - s * y, s * x + c * y

    def point_to_common(self, x: float, y: float) -> tuple[float, float]:
        rx, ry = self._rot(x, y, 1.0)
        return rx + self.origin[0], ry + self.origin[1]

    def point_to_table(self, x: float, y: float) -> tuple[float, float]:
        return self._rot(x - self.origin[0], y - self.origin[1], -1.0)

    def area_to_common(self, area: Area) -> list[tuple[float, float]]:
        """``area``'s corners in the common frame, counter-clockwise from
        (x_min, y_min) of the table frame."""
        table = [
            (area.x_min, area.y_min),
            (area.x_max, area.y_min),
            (area.x_max, area.y_max),
            (area.x_min, area.y_max),
        ]
        return [self.point_to_common(x, y) for x, y in table]

    def to_common(self, pose: Pose) -> Pose:
        """A table-frame pose in the common frame."""
        x, y = self.point_to_common(pose.x, pose.y)
        vx, vy = self._rot(pose.vx, pose.vy, 1.0)
        return Pose(x, y, pose.heading + self.rotation, vx, vy, pose.omega)

    def to_table(self, pose: Pose) -> Pose:
        """A common-frame pose in the table frame."""
        x, y = self.point_to_table(pose.x, pose.y)
        vx, vy = self._rot(pose.vx, pose.vy, -1.0)
        return Pose(x, y, pose.heading - self.rotation, vx, vy, pose.omega)

    def track_to_table(self, track: Track) -> Track:
        x, y = self.point_to_table(track.x, track.y)
        vx, vy = self._rot(track.vx, track.vy, -1.0)
        ax, ay = self._rot(track.ax, track.ay, -1.0)
        return Track(x, y, vx, vy, ax, ay)


@dataclass(frozen=True)
class Area:
    """An axis-aligned rectangle of the table frame, m."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def __post_init__(self) -> None:
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError(f"empty area {self}")

    @classmethod
    def of(cls, config: PlatformConfig) -> Area:
        """The platform's usable area (:attr:`~schemas.platform.PlatformConfig.usable_area`)."""
        return cls(*config.usable_area)

    def contains(self, x: float, y: float) -> bool:
        return self.x_min <= x <= self.x_max and self.y_min <= y <= self.y_max

    def clamp(self, track: Track) -> tuple[Track, bool]:
        """The track with its point inside the area; on a clamped axis the rates that
        push outwards are dropped. Returns (track, whether it was clamped)."""
        x = min(max(track.x, self.x_min), self.x_max)
        y = min(max(track.y, self.y_min), self.y_max)
        if x == track.x and y == track.y:
            return track, False
        vx, ax = (track.vx, track.ax) if x == track.x else (0.0, 0.0)
        vy, ay = (track.vy, track.ay) if y == track.y else (0.0, 0.0)
        return Track(x, y, vx, vy, ax, ay), True


class FramedPlatform:
    """A platform seen in the common frame, kept inside its area.

    Parameters
    ----------
    inner : Platform
        The platform (simulated or real), in its table frame.
    frame : Frame
        Its table in the common frame.
    area : Area, optional
        The usable area, table frame; None: ``inner.config``'s usable area (a platform
        with no physical description has no area: nothing is clamped or held).
    """

    def __init__(self, inner: Platform, frame: Frame, area: Area | None = None):
        self.inner = inner
        self.frame = frame
        config = inner.config
        self.area = area if area is not None else (Area.of(config) if config else None)
        self.workspace_held = False
        self.area_detail: str | None = None
        """Where the platform left its area (free text for the log and the run's
        events) while :attr:`workspace_held`; None otherwise."""
        self.workspace_counters: dict[Count, int] = {
            Count.WORKSPACE_CLAMPED: 0,
            Count.WORKSPACE_HOLDS: 0,
        }
        self.table_pose = Pose()
        """The last estimate, table frame."""
        # Half a pair's acceleration: what the platform can surely brake with.
        self._brake = 0.5 * config.pair_force / config.mass if config else None

    # -- Platform ----------------------------------------------------------------------
    @property
    def rate(self) -> float:
        return self.inner.rate

    @property
    def config(self) -> PlatformConfig | None:
        return self.inner.config

    @property
    def held(self) -> bool:
        return self.inner.held

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """One step with a common-frame reference; returns the common-frame estimate."""
        table_track = None
        if track is not None:
            table_track = self.frame.track_to_table(track)
            if self.area is not None:
                table_track, clamped = self.area.clamp(table_track)
                if self._brake is not None and self.has_fix:
                    table_track, slowed = self._stoppable(table_track)
                    clamped = clamped or slowed
                if clamped:
                    self.workspace_counters[Count.WORKSPACE_CLAMPED] += 1
        pose = self.inner.step(t, heading_ref - self.frame.rotation, rate_ref, table_track)
        self.table_pose = pose
        if (
            self.area is not None
            and not self.workspace_held
            and self.has_fix
            and not self.area.contains(pose.x, pose.y)
        ):
            self.workspace_held = True
            self.area_detail = f"left the area at ({pose.x:.3f}, {pose.y:.3f}) m, table frame"
            self.workspace_counters[Count.WORKSPACE_HOLDS] += 1
            self.inner.hold()
        return self.frame.to_common(pose)

    def _stoppable(self, track: Track) -> tuple[Track, bool]:
        """The track limited, on each axis, to what the platform can still brake to rest
        from before the area's edge it heads for, from where the estimate is: its rate
        to the speed that leaves room to stop (half a thruster pair's deceleration), and,
        if the platform already moves faster than that toward the edge, a stop where it
        is (a shared velocity, a reference running ahead of the platform, had carried it
        off its table: a hold at the edge shuts the valves, and it coasts on)."""
        assert self.area is not None and self._brake is not None
        p, a, b = self.table_pose, self.area, self._brake

        def axis(
            at: float, moving: float, ref: float, rate: float, accel: float, lo: float, hi: float
        ) -> tuple[float, float, float, bool]:
            up, down = math.sqrt(2 * b * max(0.0, hi - at)), math.sqrt(2 * b * max(0.0, at - lo))
            if not -down <= moving <= up:  # too fast toward an edge already: brake here
                return at, 0.0, 0.0, True
            limited = min(max(rate, -down), up)
            if limited == rate:
                return ref, rate, accel, False
            return ref, limited, 0.0, True

        x, vx, ax, slow_x = axis(p.x, p.vx, track.x, track.vx, track.ax, a.x_min, a.x_max)
        y, vy, ay, slow_y = axis(p.y, p.vy, track.y, track.vy, track.ay, a.y_min, a.y_max)
        if not (slow_x or slow_y):
            return track, False
        return track._replace(x=x, y=y, vx=vx, vy=vy, ax=ax, ay=ay), True

    def hold(self) -> None:
        self.inner.hold()

    def release(self) -> None:
        """Release a hold, unless the platform left its area (see :meth:`clear_workspace_hold`)."""
        if not self.workspace_held:
            self.inner.release()

    def clear_workspace_hold(self) -> None:
        """An operator brought the platform back: control may resume."""
        self.workspace_held = False
        self.area_detail = None
        self.inner.release()

    def close(self) -> None:
        self.inner.close()

    # -- what the runtime and the report read: the inner platform's, in the common frame
    @property
    def has_fix(self) -> bool:
        """Whether the estimate means anything yet (a filter's prior is not a position)."""
        return self.inner.has_fix

    @property
    def restarted(self) -> bool:
        return self.inner.restarted

    def acknowledge_restart(self) -> None:
        self.inner.acknowledge_restart()

    @property
    def cause(self) -> ClosedCause | None:
        return self.inner.cause

    @property
    def acquiring(self) -> tuple[int, int] | None:
        return self.inner.acquiring

    @property
    def last_rejection(self) -> str | None:
        return self.inner.last_rejection

    @property
    def valves(self) -> tuple[bool, ...]:
        return self.inner.valves

    @property
    def valves_confirmed(self) -> bool | None:
        return self.inner.valves_confirmed

    @property
    def truth(self) -> Pose | None:
        """A simulated platform's true pose, common frame (None for a real one)."""
        truth = self.inner.truth
        return None if truth is None else self.frame.to_common(truth)

    @property
    def counters(self) -> dict[Count, int]:
        """The inner platform's counters and the workspace's."""
        return dict(self.inner.counters) | self.workspace_counters

    @property
    def heading_pid(self) -> HeadingPid | None:
        return self.inner.heading_pid

    @property
    def chain(self) -> GncChain | None:
        """The inner platform's GNC chain, if it is flown by one (None: kinematic): for
        code that reads the chain itself rather than the capabilities above."""
        return self.inner.chain if isinstance(self.inner, WithChain) else None

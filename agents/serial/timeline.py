"""Which of a serial device's frames belong to its clock now: pure, no I/O, no clock.

Every device frame (IMU, POSE, STATUS) carries the device's time, which starts at 0 at
power-up (``docs/serial-protocol.md``). :meth:`DeviceTimeline.judge` sorts each frame by
that time and the host's time ``now`` when it was read. The rules it keeps:

1. The first frame starts the *current* timeline.
2. A frame is on a timeline when it is no more than ``tolerance`` seconds older than
   the timeline's newest frame, and no further ahead of it than the host's time has
   advanced since that frame came, plus ``tolerance`` (the device's clock cannot run
   faster than the host's; frames lost while the host stalled leave a gap no longer
   than the stall).
3. A frame on the current timeline is taken when newer than the last frame of its kind
   (``take``), dropped otherwise (``not_newer``: replayed or reordered; a STATUS may
   share its predecessor's time).
4. A frame off the current timeline is dropped (``off_timeline``). It starts a
   *candidate* timeline (the device restarted, its clock began again), which the
   following frames extend when they are on it and newer than its last frame of their
   kind; a frame on neither the current nor the candidate timeline starts a new
   candidate, and one on the current timeline ends it (a stray old frame, a replay).
5. The candidate becomes the current timeline (``restarted``: the frame is its first
   one taken) once ``confirm`` frames in a row are on it, or sooner, at its second frame,
   when a STATUS on it says no HEARTBEAT has arrived since power-up (only a device that
   restarted says so while the host sends heartbeats; one such STATUS alone, replayed
   from an earlier power-up, confirms nothing).

A single old POSE (a replay, a backlog from a previous run) or one from the future (a
corrupted time) is thus never a "restart" nor a fix, nor does it move the timeline; a
device that really restarted is heard again after ``confirm`` frames (0.1 s of IMU at
100 Hz) or its first STATUS. ``now`` only bounds how far ahead a frame may be: the
host's clock may be any clock that advances with real time.
"""

from __future__ import annotations

import math
from typing import Literal

__all__ = ["DeviceTimeline", "Kind", "Verdict"]

Kind = Literal["imu", "pose", "status"]
"""The device's frames that carry its time."""

Verdict = Literal["take", "not_newer", "off_timeline", "restarted"]
"""What to do with a frame: see the module's rules."""


class _Line:
    """A timeline: its newest time (and the host's time then), the last of each kind."""

    def __init__(self, kind: Kind, t: float, now: float):
        self.newest, self.newest_at = t, now
        self.last: dict[str, float] = {kind: t}
        self.fresh = False  # a STATUS on it said no HEARTBEAT since power-up

    def holds(self, t: float, now: float, tolerance: float) -> bool:
        ahead = self.newest + max(0.0, now - self.newest_at) + tolerance
        return self.newest - tolerance <= t <= ahead

    def newer(self, kind: Kind, t: float) -> bool:
        last = self.last.get(kind)
        return last is None or t > last or (kind == "status" and t == last)

    def add(self, kind: Kind, t: float, now: float) -> None:
        self.last[kind] = t
        if t >= self.newest:
            self.newest, self.newest_at = t, now


class DeviceTimeline:
    """Sorts a device's frames by their time: current timeline, candidate, or neither.

    Parameters
    ----------
    tolerance : float
        How far back (s) a frame may be from the newest of its timeline and still be on
        it: the host's ``fix_timeout`` (a POSE lags the IMU by the metrology's latency).
    confirm : int
        Frames in a row on a candidate timeline that confirm the device restarted.
    """

    def __init__(self, tolerance: float, confirm: int = 10):
        if not (math.isfinite(tolerance) and tolerance > 0):
            raise ValueError(f"tolerance must be positive seconds, not {tolerance!r}")
        if confirm < 1:
            raise ValueError(f"confirm must be at least 1 frame, not {confirm!r}")
        self.tolerance = tolerance
        self.confirm = confirm
        self._current: _Line | None = None
        self._candidate: _Line | None = None
        self._streak = 0

    @property
    def newest(self) -> float | None:
        """Newest device time on the current timeline, s (None before any frame)."""
        return None if self._current is None else self._current.newest

    @property
    def pending(self) -> bool:
        """A candidate timeline is waiting for confirmation: the device may have restarted."""
        return self._candidate is not None

    def judge(self, kind: Kind, t: float, now: float, *, fresh: bool = False) -> Verdict:
        """The verdict on a frame of ``kind`` at device time ``t`` (s), read at the
        host's time ``now`` (s).

        ``fresh``: a STATUS saying no HEARTBEAT has arrived since the device's power-up.
        """
        current = self._current
        if current is None:
            self._current = _Line(kind, t, now)
            return "take"
        tolerance = self.tolerance
        if current.holds(t, now, tolerance):
            self._candidate, self._streak = None, 0
            if not current.newer(kind, t):
                return "not_newer"
            current.add(kind, t, now)
            return "take"
        candidate = self._candidate
        if (
            candidate is not None
            and candidate.holds(t, now, tolerance)
            and candidate.newer(kind, t)
        ):
            candidate.add(kind, t, now)
            self._streak += 1
        else:
            candidate = self._candidate = _Line(kind, t, now)
            self._streak = 1
        candidate.fresh = candidate.fresh or (kind == "status" and fresh)
        if self._streak >= self.confirm or (candidate.fresh and self._streak >= 2):
            self._current, self._candidate, self._streak = candidate, None, 0
            return "restarted"
        return "off_timeline"

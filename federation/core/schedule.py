"""When an agent's periodic tasks are due: deadlines on fixed grids, free of I/O.

An agent's loop runs four periodic tasks: the platform's control step, pose
publication, sync requests and status. Each is due on a grid
:math:`t_0 + k\\,T`; a tick missed because the loop was late is skipped, not
made up (:func:`next_tick`), so a stall never turns into a burst. An armed
start is a deadline of its own: the control step runs when it comes, so the run
begins on time, not at the next tick.

:class:`Timetable` says what is due at ``now`` and when to wake next; the
runtime (:mod:`federation.runtime.loop`) reads the clock and does the work.
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["Due", "Timetable", "next_tick"]


def next_tick(previous: float, period: float, now: float) -> float:
    """The next deadline on the period's grid after ``previous``, past ``now``.

    .. math::

        t_{k+1} = \\begin{cases} t_k + T & \\text{if } t_k + T > \\text{now} \\\\
                  \\text{now} + T & \\text{otherwise (missed ticks skipped)} \\end{cases}
    """
    tick = previous + period
    return tick if tick > now else now + period


class Due(NamedTuple):
    """What an agent's loop must do at one instant (a named tuple: one is made at
    every tick of every agent, and a frozen dataclass cost several times more)."""

    finished: bool = False
    """The duration has passed: publish a last status and stop (nothing else runs)."""
    control: bool = False
    """Run the control step (its tick came, or an armed start, freeze or resume did)."""
    pose: bool = False
    """Publish the pose."""
    sync: bool = False
    """Send the sync requests that are due."""
    status: bool = False
    """Publish status."""
    lateness: float | None = None
    """How late the control tick runs (s); None if no control tick came."""
    overrun: bool = False
    """Control ticks were skipped: the loop fell behind by more than half a period."""


class Timetable:
    """The deadlines of one agent's periodic tasks, all on one monotonic clock (s).

    Starting at ``t0``: control every ``control_period``, pose every
    ``pose_period``, sync every ``sync_period``, each first due at ``t0`` (sync at
    ``t0 + sync_phase``: agents that tick together query on different ticks); status
    every ``status_period``, first due at ``t0 + status_period * (1 + phase)``
    (``phase`` in [0, 1): co-hosted agents report on their own phases); finished
    ``duration`` after ``t0`` (None: never).
    """

    def __init__(
        self,
        t0: float,
        control_period: float,
        pose_period: float,
        sync_period: float,
        status_period: float,
        duration: float | None = None,
        phase: float = 0.0,
        sync_phase: float = 0.0,
    ):
        self.deadline = t0 + duration if duration else math.inf
        self.control_period = control_period
        self.pose_period = pose_period
        self.sync_period = sync_period
        self.status_period = status_period
        self.next_control = self.next_pose = t0
        self.next_sync = t0 + sync_phase
        self.next_status = t0 + status_period * (1.0 + phase)

    def due(self, now: float, start_at: float = math.inf) -> Due:
        """What is due at ``now`` (an armed run starting at ``start_at``), each
        task rescheduled to its next tick."""
        if now >= self.deadline:
            return Due(finished=True)
        lateness, overrun = None, False
        control = now >= self.next_control or now >= start_at
        if now >= self.next_control:
            lateness = now - self.next_control
            following = next_tick(self.next_control, self.control_period, now)
            overrun = following - self.next_control > 1.5 * self.control_period
            self.next_control = following
        pose = now >= self.next_pose
        if pose:
            self.next_pose = next_tick(self.next_pose, self.pose_period, now)
        sync = now >= self.next_sync
        if sync:
            self.next_sync = next_tick(self.next_sync, self.sync_period, now)
        status = now >= self.next_status
        if status:
            self.next_status = next_tick(self.next_status, self.status_period, now)
        return Due(False, control, pose, sync, status, lateness, overrun)

    def next_wake(self, start_at: float = math.inf) -> float:
        """When something is due next: the earliest deadline, or an armed start, freeze
        or resume."""
        return min(
            self.next_control, self.next_pose, self.next_sync, self.next_status,
            self.deadline, start_at,
        )  # fmt: skip

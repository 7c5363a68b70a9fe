"""The agents' loop: reads the clock, runs what is due, sleeps until the next deadline.

What is due when is decided by :class:`federation.core.schedule.Timetable`;
this module only reads the host's monotonic clock, calls the agent's tasks and
waits. Agents hosted in one process share one thread (:func:`run_together`).
"""

from __future__ import annotations

import heapq
import math
import threading
import time
import zlib
from collections.abc import Callable, Sequence
from typing import Protocol, TypeVar

from federation.core.counters import Count
from federation.core.keys import AgentId
from federation.core.schedule import Timetable
from schemas.config import AgentConfig

__all__ = ["Looped", "Schedule", "run_together"]

STOP_POLL = 0.05
"""s: the longest the loop sleeps before looking at its stop event again."""


class _Appendable(Protocol):
    def append(self, value: float, /) -> None: ...


class _Rated(Protocol):
    @property
    def rate(self) -> float:
        """Control steps per second (Hz)."""


class Looped(Protocol):
    """What the loop needs of an agent (:class:`~federation.runtime.agent.AgentRuntime`)."""

    @property
    def config(self) -> AgentConfig: ...

    @property
    def me(self) -> AgentId: ...

    @property
    def platform(self) -> _Rated: ...

    @property
    def lateness(self) -> _Appendable:
        """The recent control ticks' lateness (s); the loop appends to it."""

    def count(self, name: Count) -> None: ...

    def transition_due(self) -> float:
        """Host monotonic time at which an armed start, freeze or resume applies (inf if
        none is armed)."""

    def control_step(self) -> None: ...

    def publish_pose(self) -> None: ...

    def send_sync_requests(self, now: float | None = None) -> None: ...

    def publish_status(self) -> None: ...

    def end(self) -> None:
        """Its duration has passed: hold the platform (every valve closed), then publish
        a last status."""


class Schedule:
    """One agent's periodic tasks: :meth:`tick` runs the ones due."""

    def __init__(self, agent: Looped, t0: float, slot: int = 0):
        cfg = agent.config
        self.agent = agent
        # Each agent on its own phase: co-hosted agents that reported together held
        # the interpreter for tens of ms, once a second.
        phase = zlib.crc32(str(agent.me).encode()) / 2**32
        control_period = 1.0 / agent.platform.rate
        # The ``slot``-th agent of a group that ticks together sends its sync queries
        # on its own control tick within the sync period, so that the group's queries
        # (and the replies coming back) do not all fill a link's queue at once.
        ticks = max(1, round(cfg.sync_period / control_period))
        self.timetable = Timetable(
            t0,
            control_period=control_period,
            pose_period=1.0 / cfg.pose_rate,
            sync_period=cfg.sync_period,
            status_period=cfg.status_period,
            duration=cfg.duration,
            phase=phase,
            sync_phase=(slot % ticks) * control_period,
        )

    def tick(self, now: float) -> float | None:
        """Run what is due at host monotonic ``now``; the next wake-up time, or None
        once the duration has passed (the final status is then published)."""
        agent = self.agent
        due = self.timetable.due(now, agent.transition_due())
        if due.finished:
            agent.end()  # valves closed before anything that could wait (a status put)
            return None
        if due.lateness is not None:
            agent.lateness.append(due.lateness)
        if due.overrun:
            agent.count(Count.LOOP_OVERRUNS)
        if due.control:
            agent.control_step()
        if due.pose:
            agent.publish_pose()
        if due.sync:
            agent.send_sync_requests(now)
        if due.status:
            agent.publish_status()
        return self.timetable.next_wake(agent.transition_due())


L = TypeVar("L", bound=Looped)


def run_together(
    agents: Sequence[L],
    stop: threading.Event,
    spread: float = 0.0,
    group: int = 1,
    on_end: Callable[[L], None] | None = None,
) -> None:
    """Run several agents' loops on this one thread until ``stop`` is set or every
    agent's duration has passed; each publishes a last status when it ends, and is then
    handed to ``on_end`` (to close it while the others fly on).

    Virtual agents hosted in one process (a lab's gateway, ``fedlab bench
    scale``) share a thread rather than one each: with 16 agents per process,
    16 threads waking on their own handed the interpreter lock back and forth and
    cost the kernel a third of the process's CPU. The agents tick in groups of
    ``group`` (in order), the groups' first ticks staggered evenly over ``spread``
    seconds: a group's agents run back to back on one wake-up, and the groups do
    not all wake at once. Each wake-up costs far more than the agents' own work on
    a busy host (a cold cache, a handover of the interpreter lock:
    docs/scale.md), so fewer, fuller wake-ups save CPU; one group of all the agents
    would hold the interpreter longest and delay the poses arriving meanwhile.
    Within a group each agent sends its sync queries on a control tick of its own
    (:class:`Schedule`'s ``slot``), so a group's queries do not leave in one burst.
    """
    if group < 1:
        raise ValueError(f"group must be at least 1 agent, not {group!r}")
    t0 = time.monotonic()
    step = spread / math.ceil(len(agents) / group) if agents else 0.0
    wakes = []
    for i, agent in enumerate(agents):
        at = t0 + (i // group) * step
        wakes.append((at, i, Schedule(agent, at, slot=i % group)))
    heapq.heapify(wakes)
    while wakes and not stop.is_set():
        at, i, schedule = wakes[0]
        wait = at - time.monotonic()
        if wait > 0:
            # A plain sleep, bounded so that ``stop`` is seen within STOP_POLL: waiting on
            # the event builds a condition and a lock at every wake-up (an eighth of a
            # lab process's Python time at 64 agents, profiled).
            time.sleep(min(wait, STOP_POLL))
            continue
        following = schedule.tick(time.monotonic())
        if following is None:
            heapq.heappop(wakes)
            if on_end is not None:
                on_end(agents[i])
        else:
            heapq.heapreplace(wakes, (following, i, schedule))
    for _, _, schedule in wakes:  # stopped early: the rest report once more (the caller
        schedule.agent.publish_status()  # closes them next, which holds first)

"""The agents' loop (federation/runtime/loop.py) driving stand-in agents: no Zenoh."""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import pytest

from federation.core.keys import AgentId
from federation.runtime.loop import Schedule, run_together
from schemas.config import AgentConfig


@dataclass
class Rate:
    rate: float = 100.0


@dataclass
class Stub:
    """Records what the loop asks of it, in order."""

    config: AgentConfig
    start_at: float = math.inf
    calls: list[str] = field(default_factory=list)
    counters: list[str] = field(default_factory=list)
    lateness: deque[float] = field(default_factory=deque)
    platform: Rate = field(default_factory=Rate)

    @property
    def me(self) -> AgentId:
        return self.config.agent

    def count(self, name: str) -> None:
        self.counters.append(name)

    def transition_due(self) -> float:
        return self.start_at

    def control_step(self) -> None:
        self.calls.append("control")
        self.start_at = math.inf  # the run started

    def publish_pose(self) -> None:
        self.calls.append("pose")

    def send_sync_requests(self, now: float | None = None) -> None:
        self.calls.append("sync")

    def publish_status(self) -> None:
        self.calls.append("status")

    def end(self) -> None:
        self.calls += ["hold", "status"]


def stub(**settings: Any) -> Stub:
    return Stub(AgentConfig(lab="lab0", name="a0", role="leader", **settings))


def test_a_tick_runs_the_due_tasks_in_order_and_says_when_to_wake() -> None:
    agent = stub()
    schedule = Schedule(agent, t0=100.0)
    assert schedule.tick(100.0) == pytest.approx(100.01)  # the next control tick
    assert agent.calls == ["control", "pose", "sync"]
    assert list(agent.lateness) == [0.0]


def test_an_overrun_is_counted() -> None:
    agent = stub()
    schedule = Schedule(agent, t0=0.0)
    schedule.tick(0.0)
    schedule.tick(0.2)
    assert agent.counters == ["loop_overruns"]


def test_an_armed_start_wakes_the_loop_and_runs_a_control_step() -> None:
    agent = stub()
    schedule = Schedule(agent, t0=0.0)
    schedule.tick(0.0)
    agent.start_at = 0.004
    assert schedule.timetable.next_wake(agent.transition_due()) == 0.004
    agent.calls.clear()
    assert schedule.tick(0.004) == pytest.approx(0.01)  # started: back to the grid
    assert agent.calls == ["control"] and len(agent.lateness) == 1


def test_the_duration_ends_with_the_platform_held_then_a_last_status() -> None:
    agent = stub(duration=1.0)
    schedule = Schedule(agent, t0=0.0)
    assert schedule.tick(1.0) is None
    assert agent.calls == ["hold", "status"]


@pytest.mark.timing  # real time: poses counted in 0.2 and 0.3 s of a loop
def test_run_together_runs_every_agent_for_its_duration() -> None:
    agents = [stub(duration=0.2), stub(duration=0.3, pose_rate=50.0)]
    run_together(agents, threading.Event(), spread=0.02)
    for agent, poses in zip(agents, (4, 15), strict=True):
        assert agent.calls[-1] == "status"
        assert abs(agent.calls.count("pose") - poses) <= 2


def test_a_stopped_loop_reports_once_more() -> None:
    agents = [stub(), stub()]
    stop = threading.Event()
    stop.set()
    run_together(agents, stop)
    assert [a.calls for a in agents] == [["status"], ["status"]]


@pytest.mark.timing  # real time: ticks 20 ms apart within 8 ms
def test_agents_tick_in_groups_staggered_over_the_spread() -> None:
    """Groups of ``group`` agents tick on one wake-up; the groups' first ticks are
    staggered evenly over ``spread`` (4 agents in groups of 2 over 40 ms: 0 and 20 ms)."""
    firsts: dict[int, float] = {}

    class Timed(Stub):
        def control_step(self) -> None:
            firsts.setdefault(id(self), time.monotonic())
            super().control_step()

    agents = [Timed(AgentConfig(lab="lab0", name=f"a{i}", role="leader", duration=0.1))
              for i in range(4)]  # fmt: skip
    run_together(agents, threading.Event(), spread=0.04, group=2)
    t = [firsts[id(a)] for a in agents]
    assert t[1] - t[0] < 0.005 and t[3] - t[2] < 0.005  # a group: back to back
    assert t[2] - t[0] == pytest.approx(0.02, abs=0.008)  # the next group: 20 ms on
    assert all(a.calls[-1] == "status" for a in agents)


def test_a_groups_agents_send_their_sync_queries_on_ticks_of_their_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """100 Hz control, 10 Hz sync: the 10 control ticks of a sync period hold the
    queries of a group's agents one each (the 11th shares the first's); with one
    agent a group, every agent queries at its first tick."""
    agent = stub(duration=1.0)
    firsts = [Schedule(agent, 5.0, slot=k).timetable.next_sync for k in (0, 1, 3, 9, 10)]
    assert firsts == pytest.approx([5.0, 5.01, 5.03, 5.09, 5.0])
    slots: list[int] = []

    class Recorded(Schedule):
        def __init__(self, agent: Any, t0: float, slot: int = 0):
            slots.append(slot)
            super().__init__(agent, t0, slot)

    monkeypatch.setattr("federation.runtime.loop.Schedule", Recorded)
    agents = [stub(duration=0.02) for _ in range(6)]
    run_together(agents, threading.Event(), spread=0.0, group=4)
    assert slots == [0, 1, 2, 3, 0, 1]
    slots.clear()
    run_together(agents[:3], threading.Event(), spread=0.0, group=1)
    assert slots == [0, 0, 0]


def test_a_group_has_at_least_one_agent() -> None:
    with pytest.raises(ValueError, match="group must be at least 1"):
        run_together([stub()], threading.Event(), group=0)


def test_an_agent_that_ends_is_handed_over_while_the_others_run_on() -> None:
    short, long = stub(duration=0.1), stub(duration=0.3)
    ended: list[tuple[Stub, int]] = []
    run_together(
        [short, long], threading.Event(), on_end=lambda a: ended.append((a, len(long.calls)))
    )
    assert [a for a, _ in ended] == [short, long]
    assert ended[0][1] < len(long.calls)  # the long one ran on after the short one ended
    assert short.calls[-2:] == ["hold", "status"]  # held and reported before it is handed over

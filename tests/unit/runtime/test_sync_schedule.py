"""Who an agent queries for sync, and how often: its reference and followed agent
every sync period, every other agent alive once per ``sync_others_period``, spread
so that no tick carries a burst."""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

from federation.core.keys import AgentId
from federation.runtime.agent import AgentRuntime
from schemas.config import AgentConfig


def runtime(**settings: Any) -> AgentRuntime:
    """An agent that is never started: scheduling needs no session."""
    config = AgentConfig(lab="lab0", name="a0", **settings)
    return AgentRuntime(config, session=None)  # type: ignore[arg-type]


def ticks(agent: AgentRuntime, seconds: float, start: float = 0.0) -> list[list[AgentId]]:
    """The agents queried at each sync tick over ``seconds`` from ``start`` s from now."""
    t0, period = time.monotonic() + start, agent.config.sync_period
    return [agent.due_for_sync(t0 + k * period) for k in range(round(seconds / period))]


def test_a_leader_queries_every_other_agent_once_a_second_spread_over_the_ticks() -> None:
    leader = runtime(role="leader")
    for i in range(1, 64):
        leader.peer_seen(AgentId(f"lab{i % 4}", f"a{i}"), alive=True)
    queried = ticks(leader, 10.0)  # 100 ticks of 0.1 s
    per_agent = Counter(a for tick in queried for a in tick)
    assert set(per_agent) == set(leader.peers)
    assert all(9 <= n <= 11 for n in per_agent.values()), per_agent  # 1 Hz, not 10 Hz
    # 63 agents a second over 10 ticks: about 6 per tick, never a burst of all of them.
    assert max(len(tick) for tick in queried) <= 9, [len(t) for t in queried]


def test_a_follower_queries_its_leader_every_tick_and_the_rest_once_a_second() -> None:
    follower = runtime(role="follower", follow="lab0/leader")
    leader, other = AgentId("lab0", "leader"), AgentId("lab1", "other")
    follower.peer_seen(other, alive=True)
    follower.peer_seen(leader, alive=True)
    queried = ticks(follower, 5.0)
    assert all(leader in tick for tick in queried)  # 10 Hz from the first tick
    assert sum(other in tick for tick in queried) in (4, 5, 6)
    # An agent that left is not queried; back again, it is.
    follower.peer_seen(leader, alive=False)
    assert not any(leader in tick for tick in ticks(follower, 1.0, start=5.0))
    follower.peer_seen(leader, alive=True)
    assert all(leader in tick for tick in ticks(follower, 1.0, start=6.0))


def test_sync_with_names_the_only_agents_queried_every_tick() -> None:
    member = runtime(role="member", sync_with=["lab1/b"], sync_others_period=0.2)
    member.peer_seen(AgentId("lab1", "b"), alive=True)
    member.peer_seen(AgentId("lab2", "c"), alive=True)
    queried = ticks(member, 2.0)
    assert all(tick == [AgentId("lab1", "b")] for tick in queried)


def test_status_lists_only_the_agents_queried() -> None:
    follower = runtime(role="follower", follow="lab0/leader")
    follower.peer_seen(AgentId("lab0", "leader"), alive=True)
    follower.peer_seen(AgentId("lab1", "other"), alive=True)
    assert follower.status().peers == {}
    t0 = time.monotonic()
    for agent in follower.due_for_sync(t0):
        if agent == AgentId("lab0", "leader"):
            follower.peers[agent].client.request(t0)  # what send_sync_requests does
    assert set(follower.status().peers) == {"lab0/leader"}

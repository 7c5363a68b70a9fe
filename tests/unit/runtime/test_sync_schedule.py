"""Who an agent queries for sync, and how often: its reference and followed agent
every sync period; the reference (or an agent with ``sync_all``) also every other
agent alive once per ``sync_others_period``, spread so that no tick carries a burst;
others only when their poses carry no stamp on this agent's reference (issue 17)."""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import pytest

from federation.core import wire
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


def test_a_leader_queries_every_other_agent_once_a_second_spread_over_the_ticks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    leader = runtime(role="leader")
    # Every peer seen at one instant: each first request's phase counts from when its
    # peer was seen, and on a loaded host the loop below can span a tick (10 on one
    # tick, in a make check run), which is the host's time, not the spread's.
    seen_at = time.monotonic()
    with monkeypatch.context() as frozen:
        frozen.setattr(time, "monotonic", lambda: seen_at)
        for i in range(1, 64):
            leader.peer_seen(AgentId(f"lab{i % 4}", f"a{i}"), alive=True)
    queried = ticks(leader, 10.0)  # 100 ticks of 0.1 s
    per_agent = Counter(a for tick in queried for a in tick)
    assert set(per_agent) == set(leader.peers)
    assert all(9 <= n <= 11 for n in per_agent.values()), per_agent  # 1 Hz, not 10 Hz
    # 63 agents a second over 10 ticks: about 6 per tick, never a burst of all of them.
    assert max(len(tick) for tick in queried) <= 9, [len(t) for t in queried]


def test_a_follower_queries_its_leader_every_tick_and_no_one_else() -> None:
    follower = runtime(role="follower", follow="lab0/leader")
    leader, other = AgentId("lab0", "leader"), AgentId("lab1", "other")
    follower.peer_seen(other, alive=True)
    follower.peer_seen(leader, alive=True)
    queried = ticks(follower, 5.0)
    assert all(tick == [leader] for tick in queried)  # 10 Hz from the first tick
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


def test_with_sync_all_a_follower_also_queries_the_rest_once_a_second() -> None:
    follower = runtime(role="follower", follow="lab0/leader", sync_all=True)
    leader, other = AgentId("lab0", "leader"), AgentId("lab1", "other")
    follower.peer_seen(other, alive=True)
    follower.peer_seen(leader, alive=True)
    queried = ticks(follower, 5.0)
    assert all(leader in tick for tick in queried)
    assert sum(other in tick for tick in queried) in (4, 5, 6)


def test_sync_requests_grow_linearly_with_the_federation() -> None:
    """Each agent's queries over 10 s, with the default settings: the leader (the
    reference) queries every follower once a second, each follower only the leader."""

    def total(n: int) -> int:
        names = [AgentId(f"lab{i % 4}", f"a{i}") for i in range(n)]
        count = 0
        for me in names:
            settings: dict[str, Any] = {"role": "leader"}
            if me != names[0]:
                settings = {"role": "follower", "follow": str(names[0])}
            agent = AgentRuntime(
                AgentConfig(lab=me.lab, name=me.name, **settings),
                session=None,  # type: ignore[arg-type]
            )
            for other in names:
                if other != me:
                    agent.peer_seen(other, alive=True)
            count += sum(len(tick) for tick in ticks(agent, 10.0))
        return count

    per_agent = {n: total(n) / (n - 1) for n in (4, 16, 64)}
    # 100 queries to the leader per follower, 10 from the leader per follower (+-1).
    assert all(105 <= v <= 115 for v in per_agent.values()), per_agent


def test_a_sender_without_a_reference_stamp_is_synced_pairwise() -> None:
    follower = runtime(role="follower", follow="lab0/leader")
    leader, legacy = AgentId("lab0", "leader"), AgentId("lab2", "legacy")
    follower.peer_seen(leader, alive=True)
    follower.peer_seen(legacy, alive=True)
    assert not any(legacy in tick for tick in ticks(follower, 2.0))
    follower.peer_table.place(legacy, 1.0, None)  # its pose came without an attachment
    queried = ticks(follower, 5.0, start=2.0)
    assert all(leader in tick for tick in queried)
    assert sum(legacy in tick for tick in queried) in (4, 5, 6)


def test_a_stamp_on_another_reference_is_not_used() -> None:
    follower = runtime(role="follower", follow="lab0/leader")
    assert follower.ref_id == wire.reference_id("lab0/leader")
    assert follower.reference_stamp(3.0) == wire.encode_stamp(follower.ref_id, None, None)


def test_others_uses_the_senders_stamp_without_an_offset_estimate() -> None:
    member = runtime(role="member", reference="lab0/leader")
    leader, other, legacy = AgentId("lab0", "leader"), AgentId("lab1", "b"), AgentId("lab2", "c")
    pose = wire.Pose(x=1.0)
    for agent, t, stamp in (
        (leader, 5.0, wire.RefStamp(member.ref_id, 5.0, 0.0)),
        (other, 105.0, wire.RefStamp(member.ref_id, 5.25, 0.0004)),
        (legacy, 7.0, None),
    ):
        member.peer_table.place(agent, t, stamp)
        member.latest_poses[agent] = wire.PoseSample(t, pose)
    # Placed from their stamps; the legacy agent's waits for a pairwise estimate.
    assert member.others() == {"lab0/leader": (5.0, pose), "lab1/b": (5.25, pose)}
    assert member.peer_table.pairwise == {legacy}
    # A newer pose without a stamp is not placed with the old stamp.
    member.latest_poses[other] = wire.PoseSample(106.0, pose)
    assert "lab1/b" not in member.others()


def test_the_reference_stamps_its_own_clock_with_a_zero_bound() -> None:
    leader = runtime(role="leader")
    stamp = wire.decode_stamp(leader.reference_stamp(12.5))
    assert stamp == wire.RefStamp(wire.reference_id("lab0/a0"), 12.5, 0.0)

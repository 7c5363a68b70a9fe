"""Sync links shared by the agents of a process on one clock, on a real Zenoh session:
one exchange with the reference for all of them, every one admitting each reply (a
contested reference holds them all), and another agent taking over the requests
when the one sending them leaves."""

from __future__ import annotations

import time

import zenoh
from cohosted import (
    LEAD,
    Tally,
    cohosted,
    follower_config,
    leader_config,
    reply,
    run_for,
    run_ticks,
)

from federation.core.keys import AgentId
from federation.runtime import links as links_module
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from federation.runtime.fanout import Fanout
from federation.runtime.links import SyncLink, SyncLinks


# -- the registry ------------------------------------------------------------------
def test_a_link_is_shared_by_key_and_sent_by_one() -> None:
    links = SyncLinks()
    a, b, c = object(), object(), object()

    def make() -> SyncLink:
        return SyncLink(LEAD, "k", None)  # type: ignore[arg-type]

    one = links.join(a, ("clock", LEAD), make)
    assert links.join(b, ("clock", LEAD), make) is one
    other = links.join(c, ("another clock", LEAD), make)
    assert other is not one and len(links) == 2
    assert one.agents == (a, b) and one.sharing == 2
    assert links.claim(one, b) and not links.claim(one, a)  # the first to ask sends
    emptied, orphaned = links.leave(b)
    assert emptied == [] and orphaned == [one] and one.sender is None
    assert links.claim(one, a)  # the one left takes over
    emptied, orphaned = links.leave(a)
    assert emptied == [one] and orphaned == [] and len(links) == 1


# -- on a session --------------------------------------------------------------------
def test_agents_on_one_clock_share_one_exchange_with_their_reference(
    session: zenoh.Session,
) -> None:
    """Two followers on one clock: one link, one request every sync period for both
    (the leader serves half the requests it serves to followers on clocks of their
    own), and each reports the same estimate, saying two agents share it."""
    served: dict[bool, int] = {}
    sync_ticks: dict[bool, tuple[int, int]] = {}
    for shared in (True, False):
        fanout, links, clock = Fanout(session), SyncLinks(), ExecClock()
        kinds = [leader_config(), follower_config("f1"), follower_config("f2")]
        agents = [
            AgentRuntime(c, session, clock if shared else None, fanout=fanout, links=links)
            for c in kinds
        ]
        lead, f1, f2 = agents
        ticks = [Tally(f, "send_sync_requests") for f in (f1, f2)]
        for agent in agents:
            agent.start()
        try:
            run_ticks(agents, ticks[0], 20, timeout=10.0)  # 2 s at 10 Hz
            served[shared] = lead.counters["sync_requests_served"]
            sync_ticks[shared] = ticks[0].n, ticks[1].n
            one, two = f1.peers[LEAD], f2.peers[LEAD]
            if shared:
                assert one.link is two.link and one.client is two.client
                view = f1.status().peers[str(LEAD)]
                assert view.sharing == 2 and view.samples >= 10
                assert view.offset == f2.status().peers[str(LEAD)].offset
                assert f1.reference_offset(clock.now()) is not None
                assert f2.readiness(clock.now()).reference_locked is False  # window: 3 s
            else:
                assert one.link is not two.link
                assert f1.status().peers[str(LEAD)].sharing == 1
        finally:
            for agent in agents:
                agent.close()
        assert len(links) == 0  # every link left, its querier undeclared
    # A request every sync tick (10 a second): once for both followers, or once each.
    # Judged per tick, not per second, so that the ticks a stalled host skipped are not
    # counted as requests lost: 14 to 26 of 20, and 32 of 40 at least.
    one, _ = sync_ticks[True]
    assert 0.7 * one <= served[True] <= 1.3 * one, (served, sync_ticks)
    assert served[False] >= 0.8 * sum(sync_ticks[False]), (served, sync_ticks)


def test_when_the_sender_leaves_another_agent_on_the_link_takes_over(
    session: zenoh.Session,
) -> None:
    configs = (leader_config(), follower_config("f1"), follower_config("f2"))
    with cohosted(session, *configs) as (_, links, (lead, f1, f2)):
        run_for([lead, f1, f2], 1.0)
        link = f2.peers[LEAD].link
        assert link.sender is f1
        sent = link.client.sent
        f1.close()
        ticks = Tally(f2, "send_sync_requests")
        run_ticks([lead, f2], ticks, 10, timeout=10.0)  # 1 s at 10 Hz
        assert link.sender is f2 and link.agents == (f2,)
        assert link.client.sent >= sent + 7  # at 7 of f2's 10 sync ticks at least, by f2 now
        assert f2.status().peers[str(LEAD)].sharing == 1
    assert len(links) == 0


def test_when_the_senders_loop_ends_first_another_agent_takes_over(
    session: zenoh.Session,
) -> None:
    """Agents of one process with different durations: the sender's loop ends after
    1 s, the other's after 3 s, which queries the leader itself from then on."""
    configs = (
        leader_config(),
        follower_config("f1", duration=1.0),
        follower_config("f2", duration=3.0),
    )
    with cohosted(session, *configs) as (_, _, (lead, f1, f2)):
        ticks = Tally(f2, "send_sync_requests")
        run_for([lead, f1, f2], 4.0)
        link = f2.peers[LEAD].link
        assert link.sender is f2
        # One request a sync tick of f2's (30 in its 3 s; f1 sent on the first 10), less
        # the two periods before f2 took over and four more; per tick, not per second, so
        # that ticks a stalled host skipped are not counted as requests lost.
        assert ticks.n >= 10 and link.client.sent >= ticks.n - 6, (link.client.sent, ticks.n)


# -- a reply, for every agent on the link --------------------------------------------
def test_a_reply_is_taken_once_for_all_and_a_contested_reference_holds_them_all(
    session: zenoh.Session,
) -> None:
    links, clock = SyncLinks(), ExecClock()
    f1, f2 = (AgentRuntime(follower_config(n), session, clock, links=links) for n in ("f1", "f2"))
    for agent in (f1, f2):
        agent.peer_seen(LEAD, True)
    link = f1.peers[LEAD].link
    assert f2.peers[LEAD].link is link
    for _ in range(3):  # the estimate comes with the third exchange that agrees
        links_module.on_link_reply(link, reply(link, clock.now(), "aaaa"))  # type: ignore[arg-type]
    assert link.client.accepted == 3
    assert f1.reference_offset(clock.now()) == f2.reference_offset(clock.now()) is not None

    # Another session answers for the leader: every agent on the link finds it
    # contested, the reply is dropped and the estimate they share is gone.
    links_module.on_link_reply(link, reply(link, clock.now(), "bbbb"))  # type: ignore[arg-type]
    assert link.client.accepted == 3
    for agent in (f1, f2):
        assert agent.counters["contested"] == 1
        assert agent.reference_offset(clock.now()) is None
        t_exec, host = clock.read()
        assert agent.watches.watch_contest(t_exec, host)  # held: valves closed
        assert agent.hold == "contested"


def test_agents_on_clocks_of_their_own_do_not_share(session: zenoh.Session) -> None:
    links, clock = SyncLinks(), ExecClock()
    stepped = follower_config("s", clock_step=(5.0, 0.25))
    agents = [
        AgentRuntime(follower_config("f1"), session, clock, links=links),
        AgentRuntime(follower_config("f2"), session, ExecClock(), links=links),  # own clock
        AgentRuntime(stepped, session, clock, links=links),  # a rehearsal steps its clock
    ]
    for agent in agents:
        agent.peer_seen(LEAD, True)
    assert len({id(a.peers[LEAD].link) for a in agents}) == 3


def test_only_the_agents_queried_get_a_link(session: zenoh.Session) -> None:
    """A follower among many queries its leader and no one else: the others are known
    (alive or not) without a link, a client or an estimate. One whose poses come
    without a stamp on its reference is queried pairwise from then on, on a link."""
    links, clock = SyncLinks(), ExecClock()
    configs = [follower_config(f"f{i}") for i in range(8)]
    followers = [AgentRuntime(c, session, clock, links=links) for c in configs]
    others = [AgentId("lab2", f"x{i}") for i in range(50)]
    for agent in followers:
        agent.peer_seen(LEAD, True)
        for other in others:
            agent.peer_seen(other, True)
    linked = {id(p.link) for a in followers for p in a.peers.values() if p.link is not None}
    assert len(linked) == 1  # the leader's, shared by all eight
    f0 = followers[0]
    assert all(f0.peers[o].link is None and f0.peers[o].client is None for o in others)
    assert f0.timebase.offset(others[0], clock.now()) is None
    assert others[0] not in f0.due_for_sync(time.monotonic() + 100.0)
    # A pose without a reference stamp: queried pairwise, on a link of its own.
    f0.peer_table.place(others[0], 1.0, None)
    assert f0.peers[others[0]].link is not None
    assert f0.peers[others[1]].link is None
    assert others[0] in f0.due_for_sync(time.monotonic() + 100.0)
    # Senders that turn pairwise together keep the phases of when they were seen:
    # they are not all queried on one tick.
    f0.peer_table.place(others[4], 1.0, None)
    f0.peer_table.place(others[5], 1.0, None)
    phases = [f0.peers[o].link.next_sync for o in (others[4], others[5])]  # type: ignore[union-attr]
    assert abs(phases[0] - phases[1]) > 0.05 * f0.config.sync_others_period, phases
    # One not seen yet: linked when its liveliness comes.
    late = AgentId("lab3", "late")
    f0.peer_table.place(late, 1.0, None)
    f0.peer_seen(late, True)
    assert f0.peers[late].link is not None
    # Gone and back: a peer not queried stays without a link.
    f0.peer_seen(others[2], False)
    f0.peer_seen(others[2], True)
    assert f0.peers[others[2]].link is None


def test_the_reference_queries_and_links_every_agent(session: zenoh.Session) -> None:
    lead = AgentRuntime(leader_config(), session, ExecClock(), links=SyncLinks())
    others = [AgentId("lab2", f"x{i}") for i in range(10)]
    for other in others:
        lead.peer_seen(other, True)
    assert all(lead.peers[o].link is not None for o in others)
    # Agents that restart together keep the phases of when they were first seen:
    # the reference does not query them all on one tick when they come back.
    for other in others[:2]:
        lead.peer_seen(other, False)
    for other in others[:2]:
        lead.peer_seen(other, True)
    phases = [lead.peers[o].link.next_sync for o in others[:2]]  # type: ignore[union-attr]
    assert abs(phases[0] - phases[1]) > 0.05 * lead.config.sync_others_period, phases

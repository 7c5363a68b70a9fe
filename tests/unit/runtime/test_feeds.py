"""Pose feeds shared by the followers of one agent in a process, on a real Zenoh
session: each pose is admitted once for all of them, the link is measured once, and
each follower keeps its own safe hold: a contested leader holds them all, a leader
that stops holds each of them, judged by the threshold the feed measured."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
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

from federation.core import wire
from federation.core.sync import serve
from federation.runtime import links as links_module
from federation.runtime.agent import AgentRuntime
from federation.runtime.agent import intake as intake_module
from federation.runtime.clock import ExecClock
from federation.runtime.fanout import Fanout
from federation.runtime.links import PoseFeed, SyncLinks


def test_followers_on_one_link_take_each_pose_once(
    session: zenoh.Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two followers on one clock: one feed, whose handler runs once per pose for
    both; each stores, counts and places every pose; one watch measures the link."""
    calls = []
    handler = intake_module._admit_on_feed

    def counted(feed: PoseFeed, sample: Any, users: Any, host: float, t_recv: float) -> Any:
        calls.append(users[0].owner)
        return handler(feed, sample, users, host, t_recv)

    monkeypatch.setattr(intake_module, "_admit_on_feed", counted)
    configs = (leader_config(), follower_config("f1"), follower_config("f2"))
    with cohosted(session, *configs) as (fanout, links, (lead, f1, f2)):
        poses = Tally(lead, "publish_pose")
        run_ticks([lead, f1, f2], poses, 70, timeout=20.0)  # 3.5 s at 20 Hz: the link
        # is measured from its 41st pose on
        feed = f1.feed
        assert feed is not None and f2.feed is feed and feed.agents == (f1, f2)
        assert lead.feed is None  # a leader follows no one
        for follower in (f1, f2):
            assert follower.counters["pose_received"] >= 50  # of the leader's 70
            assert LEAD in follower.latest_poses and LEAD in follower.peer_table.latest_ref
            assert follower.status().pose_age is not None
        assert f1.counters["pose_received"] == f2.counters["pose_received"] == len(calls)
        assert {id(c) for c in calls} == {id(f1)}  # the first on the feed, for both
        assert feed.watch.period == pytest.approx(0.05, abs=0.01)  # measured once
        assert f1.link_watch.period is None  # a follower's own watch only holds
    assert fanout._subscribers == {}  # the last to leave the feed unsubscribed
    assert len(links) == 0


def test_a_leader_that_stops_holds_every_follower_on_the_feed(session: zenoh.Session) -> None:
    """The leader's loop ends after 4 s (the link measured by then: its 80 poses less
    the 39 a stalled host may skip), the followers' after 5.5 s: each follower enters a
    stale safe hold of its own and ends in it."""
    configs = (
        leader_config(duration=4.0),
        *(follower_config(n, duration=5.5) for n in ("f1", "f2")),
    )
    with cohosted(session, *configs) as (_, _, (lead, f1, f2)):
        run_for([lead, f1, f2], 6.5)
        assert f1.feed is f2.feed is not None
        assert f1.feed.watch.period is not None  # measured from the poses, once
        for follower in (f1, f2):
            assert follower.counters["stale_holds"] >= 1  # a busy host may add one
            assert follower.hold == "stale"
            assert follower.platform.held  # type: ignore[attr-defined]


# -- faults, fed to the feed directly --------------------------------------------------
class _Sample:
    """What a feed reads of a :class:`federation.runtime.fanout.Received`."""

    def __init__(self, t: float, source: str, payload: bytes | None = None, stamp: Any = None):
        self.arrived = time.monotonic()
        self.key = "fedlab/default/lab0/lead/pose"
        self._payload = wire.encode_pose(t, wire.Pose()) if payload is None else payload
        self.size = len(self._payload)
        self._source, self._stamp = source, stamp

    def source(self) -> str:
        return self._source

    def pose(self) -> wire.PoseSample:
        return wire.decode_pose(self._payload)

    def stamp(self) -> Any:
        return self._stamp


@contextmanager
def _feed_of_two(session: zenoh.Session) -> Iterator[tuple[AgentRuntime, AgentRuntime, PoseFeed]]:
    """Two followers of the leader on one feed, the leader seen alive (closed after)."""
    with cohosted(session, follower_config("f1"), follower_config("f2")) as (_, _, (f1, f2)):
        for agent in (f1, f2):
            agent.peer_seen(LEAD, True)
        assert f1.feed is not None and f1.feed is f2.feed
        yield f1, f2, f1.feed


def test_a_contested_leader_holds_every_follower_on_the_feed(session: zenoh.Session) -> None:
    with _feed_of_two(session) as (f1, f2, feed):
        now = f1.clock.now()
        intake_module.on_feed_pose(feed, _Sample(now, "aaaa"))  # type: ignore[arg-type]
        assert LEAD in f1.latest_poses and LEAD in f2.latest_poses
        # A second session publishes the leader's pose: contested for both followers,
        # the pose dropped, what came before forgotten, the shared estimate reset.
        intake_module.on_feed_pose(feed, _Sample(now + 0.05, "bbbb"))  # type: ignore[arg-type]
        for follower in (f1, f2):
            assert follower.counters["contested"] == 1
            assert follower.counters["pose_received"] == 1
            assert LEAD not in follower.latest_poses
            assert str(LEAD) in follower.contested()
            t_exec, host = follower.clock.read()
            assert follower.watches.watch_contest(t_exec, host)  # held: valves closed
            assert follower.hold == "contested"
        # Nothing more from it is used while contested, from either source.
        intake_module.on_feed_pose(feed, _Sample(now + 0.1, "aaaa"))  # type: ignore[arg-type]
        assert f1.counters["contested_dropped"] == f2.counters["contested_dropped"] == 2
        assert LEAD not in f1.latest_poses and LEAD not in f2.latest_poses
        # The leader rejoins (a new session): its record starts clean for both.
        for follower in (f1, f2):
            follower.peer_seen(LEAD, False)
            follower.peer_seen(LEAD, True)
        assert f1.contested() == f2.contested() == {}


def test_each_follower_holds_by_the_threshold_the_feed_measured(
    session: zenoh.Session,
) -> None:
    with _feed_of_two(session) as (f1, f2, feed):
        t_exec, host = f1.clock.read()
        for follower in (f1, f2):
            follower.pose_received_at[LEAD] = t_exec - 0.3  # the last pose 0.3 s ago
        feed.watch.threshold = 0.5  # as measured on a jittery link
        f1.watches.watch_link(t_exec, host)
        assert f1.hold == "waiting"  # not stale: 0.3 s is within it (floor 0.15 s)
        feed.watch.threshold = 0.25
        f1.watches.watch_link(t_exec, host)
        assert f1.hold == "stale" and f1.platform.held  # type: ignore[attr-defined]
        assert f2.hold == "waiting"  # each hold its own: f2 has not looked yet
        f2.watches.watch_link(t_exec, host)
        assert f2.hold == "stale"


def test_malformed_oversized_and_late_poses_are_dropped_and_counted_for_each(
    session: zenoh.Session,
) -> None:
    with _feed_of_two(session) as (f1, f2, feed):
        now = f1.clock.now()
        bad = [
            _Sample(now, "aaaa", payload=b"\x00" * 5),  # not a pose
            _Sample(now, "aaaa", payload=b"\x00" * 4096),  # far larger than one
        ]
        for sample in bad:
            intake_module.on_feed_pose(feed, sample)  # type: ignore[arg-type]
        for follower in (f1, f2):
            assert follower.counters["pose_malformed"] == 1
            assert follower.counters["pose_oversized"] == 1
            assert LEAD not in follower.latest_poses
        # With the leader's clock known (offset 0), a pose 2 s old on arrival is late.
        link = f1.peers[LEAD].link
        with link.lock:
            for _ in range(3):
                t1 = f1.clock.now()
                served = serve(link.client.request(t1), t1 + 0.001, wire.Pose(), t1 + 0.001)
                link.client.receive(served.payload, t1 + 0.002)
        assert f1.reference_offset(f1.clock.now()) is not None
        intake_module.on_feed_pose(feed, _Sample(f1.clock.now() - 2.0, "aaaa"))  # type: ignore[arg-type]
        for follower in (f1, f2):
            assert follower.counters["pose_stale_dropped"] == 1
            assert LEAD not in follower.latest_poses  # never reaches a controller


def test_a_reordered_pose_never_replaces_a_newer_one(session: zenoh.Session) -> None:
    """A pose no newer than the last from its source (reordered on the way, or
    delivered twice) is dropped and counted for each follower; the newer stays."""
    with _feed_of_two(session) as (f1, f2, feed):
        now = f1.clock.now()
        for t in (now, now + 0.05, now + 0.02, now + 0.05):
            intake_module.on_feed_pose(feed, _Sample(t, "aaaa"))  # type: ignore[arg-type]
        for follower in (f1, f2):
            assert follower.counters["pose_out_of_order"] == 2
            assert follower.latest_poses[LEAD].t == now + 0.05
        # The leader leaves and comes back (a restart): its clock may start afresh.
        for follower in (f1, f2):
            follower.peer_seen(LEAD, False)
            follower.peer_seen(LEAD, True)
        intake_module.on_feed_pose(feed, _Sample(now - 5.0, "aaaa"))  # type: ignore[arg-type]
        assert f1.latest_poses[LEAD].t == now - 5.0


def test_an_agent_on_its_own_drops_a_reordered_pose(session: zenoh.Session) -> None:
    """The same for an agent that reads every pose itself (no shared feed)."""
    with cohosted(session, follower_config("f1", watch_all=True)) as (_, _, (f1,)):
        f1.peer_seen(LEAD, True)
        assert f1.feed is None
        now = f1.clock.now()
        for t in (now + 0.05, now):
            f1.intake.on_pose(_Sample(t, "aaaa"))  # type: ignore[arg-type]
        assert f1.counters["pose_out_of_order"] == 1
        assert f1.latest_poses[LEAD].t == now + 0.05


def test_an_agent_that_joins_the_feed_late_still_sees_the_reference_restart(
    session: zenoh.Session,
) -> None:
    """f2 joins the feed after f1 heard the leader's session: news of a new session
    reaches the agents on the feed only when it changes, so f2 had taken the new one
    for the first heard and flown on."""
    with _feed_of_two(session) as (f1, f2, feed):
        f1.close()
        f2.close()
    fanout, links, clock = Fanout(session), SyncLinks(), ExecClock()
    f1 = AgentRuntime(follower_config("f1"), session, clock, fanout=fanout, links=links)
    f2 = AgentRuntime(follower_config("f2"), session, clock, fanout=fanout, links=links)
    try:
        f1.start()
        f1.peer_seen(LEAD, True)
        feed = f1.feed
        assert feed is not None
        intake_module.on_feed_pose(feed, _Sample(clock.now(), "aaaa"))  # type: ignore[arg-type]
        f2.start()  # joins the feed now
        f2.peer_seen(LEAD, True)
        assert f2.feed is feed and f2.intake.reference_zid == "aaaa"
        for follower in (f1, f2):  # a ctl run on both
            with follower.commands.lock:
                follower.run_state.mode, follower.run_state.run_id = "running", "r1"
            follower.peer_seen(LEAD, False)
            follower.peer_seen(LEAD, True)
        intake_module.on_feed_pose(feed, _Sample(clock.now(), "bbbb"))  # type: ignore[arg-type]
        for follower in (f1, f2):
            assert follower.run_state.mode == "aborted", follower.me
            assert follower.counters["reference_restarted"] == 1
    finally:
        f1.close()
        f2.close()


def test_a_clock_step_of_the_followed_agent_forgets_its_pose_order(
    session: zenoh.Session,
) -> None:
    """Its clock stepped back 30 s within the lease: every later pose had been dropped
    as out of order until its clock passed the old one, 30 s."""
    with _feed_of_two(session) as (f1, f2, feed):
        now = f1.clock.now()
        intake_module.on_feed_pose(feed, _Sample(now, "aaaa"))  # type: ignore[arg-type]
        f1.clock_stepped(LEAD, -30.0, f1.clock.now(), time.monotonic())
        intake_module.on_feed_pose(feed, _Sample(now - 30.0, "aaaa"))  # type: ignore[arg-type]
        assert f1.counters["pose_out_of_order"] == 0
        assert f2.latest_poses[LEAD].t == now - 30.0


def test_a_contest_on_either_channel_drops_what_comes_on_the_other(
    session: zenoh.Session,
) -> None:
    """The followed agent's record is the feed's for its poses and its sync replies
    alike: two repliers drop its poses for both followers, two publishers its replies."""
    for first in ("sync", "pose"):
        with _feed_of_two(session) as (f1, f2, feed):
            link = f1.peers[LEAD].link
            now = f1.clock.now()
            if first == "sync":
                for replier in ("aaaa", "bbbb"):  # another session answers for it
                    links_module.on_link_reply(link, reply(link, f1.clock.now(), replier))  # type: ignore[arg-type]
                intake_module.on_feed_pose(feed, _Sample(now, "aaaa"))  # type: ignore[arg-type]
            else:
                for source in ("aaaa", "bbbb"):  # another session publishes its pose
                    intake_module.on_feed_pose(feed, _Sample(now, source))  # type: ignore[arg-type]
                links_module.on_link_reply(link, reply(link, f1.clock.now(), "aaaa"))  # type: ignore[arg-type]
            assert link.client.accepted == (1 if first == "sync" else 0)
            for follower in (f1, f2):
                assert follower.counters["contested"] == 1, first
                assert follower.counters["contested_dropped"] == 2, first
                assert LEAD not in follower.latest_poses
                assert follower.reference_offset(follower.clock.now()) is None  # reset
                t_exec, host = follower.clock.read()
                assert follower.watches.watch_contest(t_exec, host) and follower.hold == "contested"


def test_when_the_first_follower_leaves_the_feed_serves_the_rest(session: zenoh.Session) -> None:
    configs = (leader_config(), follower_config("f1"), follower_config("f2"))
    with cohosted(session, *configs) as (fanout, _, (lead, f1, f2)):
        run_for([lead, f1, f2], 1.0)
        feed = f2.feed
        assert feed is not None and feed.agents == (f1, f2)
        f1.close()
        assert feed.agents == (f2,) and feed.subscription is not None
        received = f2.counters["pose_received"]
        poses = Tally(lead, "publish_pose")
        run_ticks([lead, f2], poses, 20, timeout=10.0)  # 1 s at 20 Hz
        assert f2.counters["pose_received"] >= received + 15  # of the leader's 20, still
        assert f2.hold is None
    assert fanout._subscribers == {}


def test_followers_that_judge_poses_differently_do_not_share_a_feed(
    session: zenoh.Session,
) -> None:
    fanout, links, clock = Fanout(session), SyncLinks(), ExecClock()
    configs = [
        follower_config("f1"),
        follower_config("f2", stale_after=0.3),  # another threshold floor
        follower_config("f3", clock_step=(5.0, 0.25)),  # a rehearsal steps its clock
        follower_config("f4", watch_all=True),  # reads every peer's pose
        follower_config("f7", federation="another"),  # another federation's agent
        follower_config("f8", reference="lab2/ref"),  # placed on another reference
    ]
    agents = [AgentRuntime(c, session, clock, fanout=fanout, links=links) for c in configs]
    agents.append(
        AgentRuntime(follower_config("f5"), session, ExecClock(), fanout=fanout, links=links)
    )
    agents.append(AgentRuntime(follower_config("f6"), session, clock, links=links))  # no Fanout
    for agent in agents:
        agent.start()
    try:
        feeds = [agent.feed for agent in agents]
        shared = [feeds[i] for i in (0, 1, 4, 5, 6)]
        assert all(feed is not None for feed in shared)
        assert len({id(feed) for feed in shared}) == 5
        assert feeds[2] is None and feeds[3] is None and feeds[7] is None
    finally:
        for agent in agents:
            agent.close()

"""Pose intake: the peers' latest poses, who may speak for each peer, and the measure
of the followed link.

A pose sample is admitted (not oversized, its peer not contested: two sources
speaking for one peer make nothing from it usable, :mod:`federation.core.contest`),
decoded with its reference stamp, dropped if too old to steer by on arrival or older
than the last taken from its source, then stored and placed on reference time. The
followers of one agent on one session share a :class:`~federation.runtime.links.PoseFeed`:
each sample is admitted once for all of them (:func:`on_feed_pose`).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Iterable
from typing import TYPE_CHECKING

from federation.core import keys, wire
from federation.core.channels import Channel
from federation.core.contest import Channel as ContestChannel
from federation.core.contest import ContestWatch, in_order
from federation.core.counters import Count
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch
from federation.runtime.fanout import Received
from federation.runtime.links import PoseFeed, SyncLink
from federation.runtime.recorder import Shared

if TYPE_CHECKING:
    import zenoh

    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.peers import PeerTable
    from federation.runtime.agent.services import AgentServices

__all__ = ["MAX_SMALL_PAYLOAD", "PoseIntake", "on_feed_pose"]

log = logging.getLogger("fedlab.agent")

MAX_SMALL_PAYLOAD = 1024
"""Bytes: a pose sample is 56, a sync request 8 and its reply 64; a payload larger than
this on those keys is junk, dropped and counted before it is copied."""


class PoseIntake:
    """What ``owner`` (an agent) has received of its peers' poses; ``peer_table`` places
    them on reference time, ``commands`` ends a run the reference no longer counts."""

    def __init__(self, owner: AgentServices, peer_table: PeerTable, commands: RunControl):
        self.owner = owner
        self.peer_table = peer_table
        self.commands = commands
        self.latest_poses: dict[AgentId, wire.PoseSample] = {}
        self.pose_received_at: dict[AgentId, float] = {}  # own clock at arrival
        # Each peer's last pose taken: (its source, its t). One from that source no newer
        # is dropped (a reordered or repeated sample); forgotten when the peer leaves.
        self._order: dict[AgentId, tuple[str | None, float]] = {}
        self._lock = threading.Lock()  # the order and the latest pose, together
        self._keys: dict[str, tuple[AgentId, str | None] | None] = {}
        # The followed link, measured from the poses' arrivals (the stale threshold).
        self.link_watch = LinkWatch(owner.config.stale_after)
        # The followed agent's poses, admitted once for the agents of this session that
        # follow it on one sync link (federation.runtime.links); None: handled here.
        self.feed: PoseFeed | None = None
        self.contest = ContestWatch()  # two sources speaking for one peer
        self._contest_lock = threading.Lock()
        self._reference_zid: str | None = None  # the session last heard for the reference
        self._zid_lock = threading.Lock()

    # -- a sample arrives ------------------------------------------------------------
    def on_pose_sample(self, sample: zenoh.Sample) -> None:
        """A pose sample from this agent's own subscriber (no shared fan-out)."""
        try:
            received = Received(sample)
        except Exception:
            log.exception("pose sample on %s unreadable", sample.key_expr)
            return
        self.on_pose(received)

    def on_pose(self, sample: Received) -> None:
        """A pose sample (read once for every agent of the process)."""
        owner = self.owner
        clock = owner.clock
        host = sample.arrived if clock.source is time.monotonic else clock.source()
        t_recv = clock.at(host)
        try:
            parsed = self._pose_key(sample.key)
            if not self._admit_pose(sample, parsed, host):
                return
            read = self.read_pose(sample, (self,))
            if read is None:
                return
            decoded, stamp = read
            owner.count(Count.POSE_RECEIVED)
            if (
                parsed is not None
                and parsed[0] == owner.follow
                and self.stale_on_arrival(decoded.t, t_recv, self.link_watch)
            ):
                owner.count(Count.POSE_STALE_DROPPED)  # never reaches the controller
                return
            if parsed is not None and not self._take(parsed[0], sample, decoded, stamp, t_recv):
                return
            if owner.recording(Channel.POSE_RECEIVED):
                message = {
                    "agent": str(parsed[0]) if parsed else sample.key,
                    "t": decoded.t, "t_recv": t_recv, "host_monotonic": host,
                    **decoded.pose._asdict(),
                }  # fmt: skip
                # Shared: a run's recording and the agent's encode it once between them.
                owner.record(Channel.POSE_RECEIVED, Shared(message))
        except Exception:
            log.exception("pose sample on %s failed", sample.key)

    def _take(
        self,
        agent: AgentId,
        sample: Received,
        decoded: wire.PoseSample,
        stamp: wire.RefStamp | None,
        t_recv: float,
    ) -> bool:
        """Store ``agent``'s pose unless older than the last from its source (counted);
        placed on reference time. True if taken."""
        with self._lock:  # judged and stored at once: no older one over it
            fresh = in_order(self._order, agent, sample.source(), decoded.t)
            if fresh:
                self.store(agent, decoded, t_recv)
        if not fresh:
            self.owner.count(Count.POSE_OUT_OF_ORDER)
            return False
        self.peer_table.place(agent, decoded.t, stamp)
        return True

    def store(self, agent: AgentId, decoded: wire.PoseSample, t_recv: float) -> None:
        """Keep ``decoded`` as ``agent``'s latest pose, arrived at own time ``t_recv``."""
        self.latest_poses[agent] = decoded
        self.pose_received_at[agent] = t_recv

    def stale_on_arrival(self, sent: float, t_recv: float, watch: LinkWatch) -> bool:
        """Whether a followed pose (stamped ``sent`` on its sender's clock, arrived at own
        ``t_recv``) is too old to steer by (a burst queued through a cut); a fresh one
        measures the link on ``watch`` for the stale threshold."""
        follow = self.owner.follow
        assert follow is not None
        client = self.peer_table.client_of(follow)  # the time base's estimate
        if client is not None:
            offset = client.estimator.offset_at(t_recv)  # the sender's clock: t_recv + offset
            if offset is not None and watch.too_old(t_recv + offset - sent, client.delay):
                return True
        watch.observe(t_recv, sent)
        return False

    def _pose_key(self, key: str) -> tuple[AgentId, str | None] | None:
        """``keys.parse_agent_key`` of a pose key, remembered: every sample of a sender
        has the same key, and parsing validates (and allocates) an AgentId each time."""
        cache = self._keys
        if key not in cache:
            if len(cache) >= 4096:  # a flood of made-up keys: start over, stay bounded
                cache.clear()
            cache[key] = keys.parse_agent_key(self.owner.config.federation, key)
        return cache[key]

    def read_pose(
        self, sample: Received, users: Iterable[PoseIntake]
    ) -> tuple[wire.PoseSample, wire.RefStamp | None] | None:
        """A pose sample's pose and reference stamp (None without one, or on another
        reference: counted by each of ``users``); None if either is malformed, counted
        by each of ``users`` and logged once."""
        try:
            decoded = sample.pose()
        except wire.DecodeError as error:
            _count_all(users, Count.POSE_MALFORMED)
            self.owner.reject("pose sample", f"{sample.key}: {error}")
            return None
        try:
            stamp = sample.stamp()
        except wire.DecodeError as error:
            _count_all(users, Count.POSE_STAMP_MALFORMED)
            self.owner.reject("pose stamp", f"{sample.key}: {error}")
            return None
        if stamp is not None and stamp.ref_id != self.owner.ref_id:
            _count_all(users, Count.POSE_OTHER_REFERENCE)
            stamp = None
        return decoded, stamp

    @property
    def reference_zid(self) -> str | None:
        """The session last heard speaking for the reference (None: none yet)."""
        return self._reference_zid

    # -- who speaks for a peer (federation.core.contest) -----------------------------
    def oversized(self, size: int, counter: Count) -> bool:
        """Drop (and count) a payload of ``size`` bytes far larger than any pose or sync
        message, before it is copied or decoded."""
        if size <= MAX_SMALL_PAYLOAD:
            return False
        self.owner.count(counter)
        return True

    def _admit_pose(
        self, sample: Received, parsed: tuple[AgentId, str | None] | None, host: float
    ) -> bool:
        """Whether a pose sample may be used: not oversized, and its peer not contested
        (its source: the publisher's session id in the source info, None without one)."""
        if self.oversized(sample.size, Count.POSE_OVERSIZED):
            return False
        if parsed is None:
            return True
        return self.contest_verdict(parsed[0], "pose", sample.source(), host)

    def admit_reply(
        self, link: SyncLink, source: str | None, size: int, host: float, feed: PoseFeed | None
    ) -> bool:
        """Whether a sync reply (its payload ``size`` bytes) may be used: not oversized,
        and the peer not contested (its ``source``: the replier's session id, which
        Zenoh sets on every reply); judged for this agent, or for every agent on
        ``feed``, whose record of the agent they follow covers its poses and its
        replies alike (a contest on one drops what comes on the other too)."""
        if size > MAX_SMALL_PAYLOAD:
            _count_all(_members(feed, self), Count.SYNC_REPLIES_OVERSIZED)
            return False
        return self.contest_verdict(link.agent, "sync", source, host, feed)

    def contest_verdict(
        self,
        agent: AgentId,
        channel: ContestChannel,
        source: str | None,
        host: float,
        feed: PoseFeed | None = None,
    ) -> bool:
        """Whether ``source`` may speak for ``agent`` on ``channel``: judged by this
        agent's contest watch, or by ``feed``'s (the record of the agent its agents
        follow) for every agent on it."""
        name = str(agent)
        watch, lock = (
            (self.contest, self._contest_lock) if feed is None else (feed.contest, feed.lock)
        )
        users = _members(feed, self)
        with lock:
            outcome = watch.observe(name, channel, source, host)
            reason = watch.reason(name, host) if outcome == "contested" else None
            spoke = outcome == "ok" and watch.new_speaker(name, source)
        if outcome == "ok":
            if spoke:  # first heard, or a new session for it
                for user in users:
                    if user.owner.reference == agent:
                        user.reference_session(source, host)
            return True
        _count_all(users, Count.CONTESTED_DROPPED)
        if outcome == "contested":
            for user in users:
                user.drop_contested(agent)
            log.error("%s is contested: %s; nothing from it is used", agent, reason)
        return False

    def drop_contested(self, agent: AgentId) -> None:
        """``agent`` is contested: what it sent so far is suspect, and the estimate of
        every agent on its link is reset (all of them hold)."""
        self.owner.count(Count.CONTESTED)
        self.latest_poses.pop(agent, None)
        peer = self.peer_table.peers.get(agent)
        link = None if peer is None else peer.link
        if link is not None:
            link.reset()

    def reference_session(self, source: str | None, host: float) -> None:
        """The session speaking for the reference is ``source`` (first heard, or new). A
        new one during a run started by ctl is the reference restarted: its new process
        waits, flies no maneuver and may count time afresh, so the run is over here
        (``reference_restarted``). A link cut longer than the lease is not: the same
        session comes back."""
        with self._zid_lock:  # Zenoh's threads for poses and for sync replies both call it
            before, self._reference_zid = self._reference_zid, source
        if before is not None and before != source:
            owner = self.owner
            detail = f"{owner.reference} restarted (session {before[:8]} now {source!s:.8})"
            self.commands.end_run_here(Count.REFERENCE_RESTARTED, detail, host)

    def contest_reason(self, name: str, host: float) -> str | None:
        """Why ``name`` is contested now, by this agent's watch or its feed's."""
        with self._contest_lock:
            reason = self.contest.reason(name, host)
        feed = self.feed
        if reason is None and feed is not None:  # its poses are judged on the feed
            with feed.lock:
                reason = feed.contest.reason(name, host)
        return reason

    def contested(self, host: float) -> dict[str, str]:
        """Every contested peer and why (status)."""
        with self._contest_lock:
            contested = self.contest.contested(host)
        feed = self.feed
        if feed is not None:  # the followed agent's poses are judged on the feed
            with feed.lock:
                contested = feed.contest.contested(host) | contested
        return contested

    # -- news ------------------------------------------------------------------------
    def forget(self, agent: AgentId) -> None:
        """``agent`` restarted or left: a new session may speak for it, and it may count
        time afresh."""
        with self._contest_lock:
            self.contest.forget(str(agent))
        with self._lock:
            self._order.pop(agent, None)
        feed = self.feed
        if feed is not None and feed.agent == agent:
            with feed.lock:
                feed.contest.forget(str(agent))
                feed.order.pop(agent, None)

    def forget_order(self, agent: AgentId) -> None:
        """``agent``'s clock stepped: its poses count time afresh (a step back would have
        every pose dropped as out of order until its clock passed the old one)."""
        with self._lock:
            self._order.pop(agent, None)
        feed = self.feed
        if feed is not None and feed.agent == agent:
            with feed.lock:
                feed.order.pop(agent, None)

    # -- a shared feed ---------------------------------------------------------------
    def join_feed(self, key: str) -> bool:
        """Follow through the pose feed shared with the agents of this session that follow
        the same agent on the same sync link, judge its poses alike and record them
        (:mod:`federation.runtime.links`); False (the agent subscribes itself) without a
        shared fan-out, or for an agent that watches every pose, has a scenario (it reads
        every peer's pose) or rehearses a clock step."""
        owner = self.owner
        cfg, follow, fanout = owner.config, owner.follow, owner.fanout
        if (
            fanout is None or follow is None or cfg.watch_all or owner.scenario is not None
            or cfg.clock_step is not None
        ):  # fmt: skip
            return False
        # What makes two agents' judgement of a pose the same: the session's shared
        # subscriptions, the clock, the link whose estimate dates the pose (the key its
        # link is shared by: the followed agent is always queried), the threshold's
        # floor and the reference whose stamps are read. Who may speak for the followed
        # agent, on pose and sync alike, is recorded on the feed (admit_reply).
        share = (
            "pose", fanout, owner.clock, follow, cfg.federation, cfg.sync_period, cfg.estimator,
            cfg.sync_window, cfg.sync_timeout, cfg.four_timestamps, cfg.stale_after, owner.ref_id,
        )  # fmt: skip
        feed = owner.links.feed(owner, share, lambda: PoseFeed(follow, LinkWatch(cfg.stale_after)))
        with feed.lock:
            if feed.subscription is None:
                feed.subscription = fanout.subscribe(key, functools.partial(on_feed_pose, feed))
            # The session its agents heard for the followed agent before this one joined:
            # news of a new one reaches only the agents on the feed when it changes.
            speaker = feed.contest.speaker(str(follow))
        if speaker is not None and follow == owner.reference:
            with self._zid_lock:
                self._reference_zid = self._reference_zid or speaker
        self.feed = feed
        return True

    def others(self, t_exec: float) -> dict[str, tuple[float, wire.Pose]]:
        """Every other agent's latest pose, stamped on simulation (reference) time: the
        reference stamp it carries (its sender's estimate, no sync with the sender
        needed) or, for a sender that does not stamp, its own clock mapped through this
        agent's offset estimates (Eq. 5)."""
        owner = self.owner
        out = {}
        latest_ref = self.peer_table.latest_ref
        for agent, sample in list(self.latest_poses.items()):
            if agent == owner.me:  # watching every pose, its own comes back too
                continue
            stamped = latest_ref.get(agent)
            if stamped is not None and stamped[0] == sample.t:  # the sender's own stamp
                out[str(agent)] = (stamped[1], sample.pose)
                continue
            t_sim = owner.timebase.peer_to_sim(agent, sample.t, t_exec)
            if t_sim is not None:
                out[str(agent)] = (t_sim, sample.pose)
        return out


def _members(feed: PoseFeed | None, alone: PoseIntake) -> list[PoseIntake]:
    """The intakes of the agents on ``feed`` (``alone``'s only, without one)."""
    if feed is None or not feed.agents:
        return [alone]
    return [agent.intake for agent in feed.agents]


def on_feed_pose(feed: PoseFeed, sample: Received) -> None:
    """A pose of the followed agent on ``feed``, for every agent on it (the first
    first): admitted once (its size, its source, its age on arrival by the estimate they
    share), the link measured once; each agent stores, counts and records it."""
    if not feed.agents:
        return
    users = [agent.intake for agent in feed.agents]
    clock = users[0].owner.clock
    host = sample.arrived if clock.source is time.monotonic else clock.source()
    t_recv = clock.at(host)
    agent = feed.agent
    try:
        read = _admit_on_feed(feed, sample, users, host, t_recv)
        if read is None:
            return
        decoded, stamp = read
        with feed.lock:  # judged and stored at once: no older one over it
            fresh = in_order(feed.order, agent, sample.source(), decoded.t)
            if fresh:
                for user in users:
                    user.store(agent, decoded, t_recv)
        if not fresh:
            _count_all(users, Count.POSE_RECEIVED)
            _count_all(users, Count.POSE_OUT_OF_ORDER)  # never overwrites a newer one
            return
    except Exception:
        log.exception("pose sample on %s failed", sample.key)
        return
    _deliver(feed, sample, users, decoded, stamp, host, t_recv)


def _admit_on_feed(
    feed: PoseFeed, sample: Received, users: list[PoseIntake], host: float, t_recv: float
) -> tuple[wire.PoseSample, wire.RefStamp | None] | None:
    """A feed's sample admitted and read once for all its agents; None if dropped."""
    first, agent = users[0], feed.agent
    if sample.size > MAX_SMALL_PAYLOAD:
        _count_all(users, Count.POSE_OVERSIZED)
        return None
    if not first.contest_verdict(agent, "pose", sample.source(), host, feed):
        return None
    read = first.read_pose(sample, users)
    if read is None:
        return None
    # Dated by the estimate of the link they share: read through the first of them that
    # has seen the agent (liveliness may reach one before another).
    judge = next((u for u in users if agent in u.peer_table.peers), first)
    if judge.stale_on_arrival(read[0].t, t_recv, feed.watch):
        _count_all(users, Count.POSE_RECEIVED)
        _count_all(users, Count.POSE_STALE_DROPPED)  # never reaches a controller
        return None
    return read


def _deliver(
    feed: PoseFeed,
    sample: Received,
    users: list[PoseIntake],
    decoded: wire.PoseSample,
    stamp: wire.RefStamp | None,
    host: float,
    t_recv: float,
) -> None:
    """Each agent counts, places and records a pose taken on the feed; one agent's
    failure does not keep the pose from the rest."""
    agent = feed.agent
    message: Shared | None = None
    for user in users:
        owner = user.owner
        try:
            owner.count(Count.POSE_RECEIVED)
            user.peer_table.place(agent, decoded.t, stamp)
            if owner.recording(Channel.POSE_RECEIVED):
                if message is None:  # built and encoded once, queued by each recorder
                    message = Shared({
                        "agent": str(agent), "t": decoded.t, "t_recv": t_recv,
                        "host_monotonic": host, **decoded.pose._asdict(),
                    })  # fmt: skip
                owner.record(Channel.POSE_RECEIVED, message)
        except Exception:
            log.exception("pose sample on %s failed for %s", sample.key, owner.me)


def _count_all(users: Iterable[PoseIntake], name: Count) -> None:
    for user in users:
        user.owner.count(name)

"""Sync links: one exchange with one peer, shared by the agents of a process on one clock.

Agents hosted in one process on one session (``fedlab bench scale``, a lab's
gateway process running several virtual agents) that read one clock (the same
:class:`~federation.runtime.clock.ExecClock` object) would each query their
reference ten times a second and each learn the same thing: the offset between
that one clock and the reference's. A :class:`SyncLinks` registry gives them one
:class:`SyncLink` per peer instead: one querier, one exchange per period, one
:class:`~federation.core.sync.SyncClient` whose estimate every agent on the link
reads. The first agent on the link that queries the peer sends the requests (the
link's ``sender``), and another takes over if it leaves or its loop ends first;
each reply is admitted, counted, recorded and logged by every agent on the link
(:func:`on_link_reply`, through the narrow :class:`LinkUser` calls).

A link is shared only by agents that would query the peer alike: the same clock
object, the same cadence (``sync_period`` or ``sync_others_period``) and the same
estimator, window, timeout and timestamps. Anything else (a clock of an agent's
own, a clock-step rehearsal, a peer an agent does not query) gets a link of its
own.

The same agents that follow one peer share its poses too: a :class:`PoseFeed`
admits each sample once for all of them (its size, who published it, its age on
arrival by the link's estimate) and measures the link once (one
:class:`~federation.core.linkwatch.LinkWatch` observing the arrivals); each agent
then only stores the pose, counts and records it, and keeps its own safe hold,
judged by the feed's measured threshold
(:func:`federation.runtime.agent.intake.on_feed_pose`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import zenoh

from federation.core import wire
from federation.core.channels import Channel
from federation.core.contest import ContestWatch
from federation.core.counters import Count
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch
from federation.core.sync import SyncClient, read_send_time
from federation.runtime.recorder import Message, Shared
from federation.runtime.syncglue import Answer, SyncQuerier

__all__ = ["LinkUser", "PoseFeed", "SyncLink", "SyncLinks", "on_link_answer", "on_link_reply"]

log = logging.getLogger("fedlab.agent")


@dataclass(eq=False)
class SyncLink:
    """One sync exchange with ``agent`` (the peer), on its ``key``."""

    agent: AgentId
    key: str
    client: SyncClient
    agents: tuple[Any, ...] = ()  # the agents that read its estimate (AgentRuntime)
    sender: Any = None  # the one of them that sends its requests
    querier: SyncQuerier | None = None  # on the peer's sync key, made on first use
    next_sync: float = 0.0  # host monotonic time of its next request
    four_timestamps: bool = False  # the replier's send time (t2s) is read and used
    # Held while the client changes (a request, a reply, a reset): its agents' threads
    # and Zenoh's callback threads all reach it.
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def sharing(self) -> int:
        """How many agents read this link's estimate."""
        return len(self.agents)

    def reset(self) -> None:
        """Forget the estimate, for every agent that reads it (the peer restarted, or
        someone else answers for it: all of them hold until it is measured again)."""
        with self.lock:
            self.client.reset()


@dataclass(eq=False)
class PoseFeed:
    """The poses of ``agent`` (the peer followed), admitted once for the agents that
    follow it on one sync link: ``watch`` measures the link from their arrivals,
    ``contest`` records who speaks for the peer (its poses, and its replies
    to these agents' sync queries)."""

    agent: AgentId
    watch: LinkWatch
    contest: ContestWatch = field(default_factory=ContestWatch)
    agents: tuple[Any, ...] = ()  # the agents that follow it (AgentRuntime)
    subscription: Any = None  # on the peer's pose key, declared by the first of them
    # The peer's last pose taken: (its source, its t); see federation.core.contest.in_order.
    order: dict[AgentId, tuple[str | None, float]] = field(default_factory=dict)
    # Held while the contest record or the subscription changes: Zenoh's callback
    # threads and the agents' threads all reach them.
    lock: threading.Lock = field(default_factory=threading.Lock)


class _Shared(Protocol):
    agents: tuple[Any, ...]


_S = TypeVar("_S", bound=_Shared)


class SyncLinks:
    """The sync links of the agents on one session, keyed by what makes two agents'
    exchanges with a peer the same (see the module's docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._links: dict[Hashable, SyncLink] = {}
        self._feeds: dict[Hashable, PoseFeed] = {}

    def join(self, user: Any, share: Hashable, make: Callable[[], SyncLink]) -> SyncLink:
        """The link keyed ``share`` (made by ``make()`` if there is none), with ``user``
        among its agents."""
        return self._join(self._links, user, share, make)

    def feed(self, user: Any, share: Hashable, make: Callable[[], PoseFeed]) -> PoseFeed:
        """The pose feed keyed ``share`` (made by ``make()`` if there is none), with
        ``user`` among its agents."""
        return self._join(self._feeds, user, share, make)

    def _join(
        self, table: dict[Hashable, _S], user: Any, share: Hashable, make: Callable[[], _S]
    ) -> _S:
        with self._lock:
            shared = table.get(share)
            if shared is None:
                shared = make()
                table[share] = shared
            if user not in shared.agents:
                shared.agents = (*shared.agents, user)
            return shared

    def leave_feeds(self, user: Any) -> list[PoseFeed]:
        """Take ``user`` off every pose feed: the feeds now without agents, whose
        subscription the caller undeclares."""
        emptied = []
        with self._lock:
            for share, feed in list(self._feeds.items()):
                if user in feed.agents:
                    feed.agents = tuple(a for a in feed.agents if a is not user)
                    if not feed.agents:
                        del self._feeds[share]
                        emptied.append(feed)
        return emptied

    def claim(self, link: SyncLink, user: Any, stalled: bool = False) -> bool:
        """Whether ``user`` sends ``link``'s requests: it does if it already did, if no
        one does (the first agent on the link that queries the peer), or if the one
        that did has ``stalled`` (sent nothing for a while: its loop ended)."""
        if link.sender is user:
            return True
        with self._lock:
            if link.sender is None or stalled:
                link.sender = user
            return link.sender is user

    def leave(self, user: Any) -> tuple[list[SyncLink], list[SyncLink]]:
        """Take ``user`` off every link: (the links now without agents, whose querier
        the caller undeclares; the links it sent on that others still read, whose
        agents must look for a sender again)."""
        emptied, orphaned = [], []
        with self._lock:
            for share, link in list(self._links.items()):
                if user not in link.agents:
                    continue
                link.agents = tuple(a for a in link.agents if a is not user)
                if not link.agents:
                    del self._links[share]
                    emptied.append(link)
                elif link.sender is user:
                    link.sender = None
                    orphaned.append(link)
        return emptied, orphaned

    def __len__(self) -> int:
        return len(self._links)


class LinkUser(Protocol):
    """What a sync link's reply fan-out asks of each agent on the link."""

    @property
    def me(self) -> AgentId: ...

    @property
    def feed(self) -> PoseFeed | None: ...

    @property
    def clock(self) -> Any: ...

    def count(self, name: Count) -> None: ...

    def admit_reply(
        self, link: SyncLink, source: str | None, size: int, host: float, feed: PoseFeed | None
    ) -> bool: ...

    def sync_answered(self, agent: AgentId) -> None: ...

    def clock_stepped(self, agent: AgentId, jump: float, t3: float, host: float) -> None: ...

    def recording(self, topic: Channel) -> bool: ...

    def record(self, topic: Channel, message: Message) -> None: ...

    def reject(self, kind: str, message: str) -> None: ...


def on_link_reply(link: SyncLink, reply: zenoh.Reply) -> None:
    """A sync reply on ``link`` as Zenoh hands it over: read at once (``t3``, on the
    clock its agents share), then :func:`on_link_answer`."""
    users: Sequence[LinkUser] = link.agents
    if users:
        on_link_answer(link, Answer(reply, *users[0].clock.read()))


def on_link_answer(link: SyncLink, answer: Answer) -> None:
    """A sync reply on ``link``, for every agent on it (the first first): each admits it
    (one that finds the replier contested drops it, and resets the estimate they share,
    so every one of them holds), the client takes it once, and each counts, logs and
    records what came of it."""
    users: Sequence[LinkUser] = link.agents
    if not users:
        return
    try:
        if not answer.ok:
            for user in users:
                user.count(Count.SYNC_REPLY_ERRORS)
            return
        if not _admitted(link, users, answer.source, answer.size, answer.host):
            return
        for user in users:
            user.sync_answered(link.agent)
        _take(link, users, answer)
    except Exception:
        log.exception("sync reply from %s failed", link.key)


def _admitted(
    link: SyncLink, users: Sequence[LinkUser], source: str | None, size: int, host: float
) -> bool:
    """Each agent judges a reply by its own contest watch, except that the followers on
    one pose feed judge their followed agent once, by the feed's (every one of them
    looks: no short cut)."""
    admitted = True
    judged: list[PoseFeed] = []
    for user in users:
        feed = user.feed
        if feed is None or feed.agent != link.agent:
            admitted &= user.admit_reply(link, source, size, host, None)
        elif all(feed is not seen for seen in judged):
            judged.append(feed)
            admitted &= user.admit_reply(link, source, size, host, feed)
    return admitted


def _take(link: SyncLink, users: Sequence[LinkUser], answer: Answer) -> None:
    """The client takes an admitted reply; a clock step and the exchange are told to
    every agent on the link."""
    t3, host = answer.t3, answer.host
    t2s = None
    attachment = answer.attachment() if link.four_timestamps else None
    if attachment is not None:
        try:
            t2s = read_send_time(attachment)
        except wire.DecodeError:
            users[0].count(Count.SYNC_ATTACHMENT_MALFORMED)
    recorders = [user for user in users if user.recording(Channel.SYNC_EXCHANGE)]
    client = link.client
    with link.lock:
        steps = client.steps
        accepted = client.receive(answer.payload(), t3, t2s)
        reason = client.last_rejection
        exchange = client.last
        estimate = client.offset_at(t3) if recorders else None
        stepped = client.steps > steps
    if stepped:
        jump = client.last_step or 0.0
        log.warning(
            "clock step of %+.3f s between %s and %s: estimate reset",
            jump, ", ".join(str(user.me) for user in users), link.agent,
        )  # fmt: skip
        for user in users:
            user.clock_stepped(link.agent, jump, t3, host)
    if accepted is None or exchange is None:
        users[0].reject(f"sync reply ({reason})", f"from {link.key}")
        return
    if not recorders:
        return
    message = Shared({  # encoded once for every agent on the link
        "peer": str(link.agent), "t1": exchange.t1, "t2": exchange.t2, "t3": exchange.t3,
        "t2s": exchange.t2s, "offset": exchange.offset, "delay": exchange.delay,
        "estimate": estimate, "host_monotonic": host,
    })  # fmt: skip
    for user in recorders:
        user.record(Channel.SYNC_EXCHANGE, message)

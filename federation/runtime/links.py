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
(:meth:`AgentRuntime._on_sync_reply`).

A link is shared only by agents that would query the peer alike: the same clock
object, the same cadence (``sync_period`` or ``sync_others_period``) and the same
estimator, window, timeout and timestamps. Anything else (a clock of an agent's
own, a clock-step rehearsal, a peer an agent does not query) gets a link of its
own, as every agent had before links were shared.

The same agents that follow one peer share its poses too: a :class:`PoseFeed`
admits each sample once for all of them (its size, who published it, its age on
arrival by the link's estimate) and measures the link once (one
:class:`~federation.core.linkwatch.LinkWatch` observing the arrivals); each agent
then only stores the pose, counts and records it, and keeps its own safe hold,
judged by the feed's measured threshold (:meth:`AgentRuntime._on_feed_pose`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

from federation.core.contest import ContestWatch
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch
from federation.core.sync import SyncClient

__all__ = ["PoseFeed", "SyncLink", "SyncLinks"]


@dataclass(eq=False)
class SyncLink:
    """One sync exchange with ``agent`` (the peer), on its ``key``."""

    agent: AgentId
    key: str
    client: SyncClient
    agents: tuple[Any, ...] = ()  # the agents that read its estimate (AgentRuntime)
    sender: Any = None  # the one of them that sends its requests
    querier: Any = None  # zenoh.Querier on the peer's sync key, declared on first use
    on_reply: Any = None  # its reply handler, made once
    next_sync: float = 0.0  # host monotonic time of its next request
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
    ``contest`` records who speaks for the peer (issue 13: its poses, and its replies
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

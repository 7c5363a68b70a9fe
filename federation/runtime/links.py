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
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

from federation.core.keys import AgentId
from federation.core.sync import SyncClient

__all__ = ["SyncLink", "SyncLinks"]


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


class SyncLinks:
    """The sync links of the agents on one session, keyed by what makes two agents'
    exchanges with a peer the same (see the module's docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._links: dict[Hashable, SyncLink] = {}

    def join(self, user: Any, share: Hashable, make: Callable[[], SyncLink]) -> SyncLink:
        """The link keyed ``share`` (made by ``make()`` if there is none), with ``user``
        among its agents."""
        with self._lock:
            link = self._links.get(share)
            if link is None:
                link = self._links[share] = make()
            if user not in link.agents:
                link.agents = (*link.agents, user)
            return link

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

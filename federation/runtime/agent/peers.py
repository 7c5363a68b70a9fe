"""The agents one agent knows: alive or not, which of them it queries for their clocks,
on which sync link, and when each is due.

Every pose carries its sender's reference time (``wire.encode_stamp``), so an agent
syncs only with its reference and the agent it follows, every ``sync_period``; the
reference itself (a monitor of every clock) or an agent with ``sync_all`` also
queries every other agent, each ``sync_others_period`` on a phase of its own. A
sender of poses without this agent's reference stamp is synced with pairwise. Sync
traffic is O(N).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from federation.core import wire
from federation.core.counters import Count
from federation.core.estimators import make_estimator
from federation.core.keys import AgentId
from federation.core.linkwatch import SilenceWatch
from federation.core.schedule import next_tick
from federation.core.sync import SyncClient
from federation.runtime.links import SyncLink, on_link_answer
from federation.runtime.status import peer_status
from federation.runtime.syncglue import SyncQuerier
from schemas.config import AgentConfig
from schemas.messages import PeerStatus, Status

if TYPE_CHECKING:
    from federation.runtime.agent.services import AgentServices

__all__ = ["Peer", "PeerTable"]

log = logging.getLogger("fedlab.agent")

_GOLDEN = 0.6180339887498949


@dataclass(slots=True)  # one per agent seen, in every agent: no __dict__ each
class Peer:
    """Another agent as this one knows it: alive or not and, if this agent queries it,
    the sync link whose estimate of its clock it reads (its own, or shared with the
    agents of its process on the same clock: :mod:`federation.runtime.links`).

    An agent not queried has no link, hence no estimate: a follower among 256 agents
    queries two of them, and a link to each of the others would grow a federation's
    memory as N squared."""

    agent: AgentId
    link: SyncLink | None = None
    alive: bool = True
    index: int = 0  # the order it was seen in: its phase if queried once a period
    client: SyncClient | None = field(init=False)  # the link's: read on every pose

    def __post_init__(self) -> None:
        self.client = None if self.link is None else self.link.client

    def attach(self, link: SyncLink) -> None:
        """Query it from now on, on ``link`` (the client is set last: a reader on
        another thread that finds the client finds the link)."""
        self.link = link
        self.client = link.client

    def offset_at(self, t: float) -> float | None:
        """Its clock minus this agent's at own time ``t`` (s): the time base's estimate
        (the client's estimator asked directly: one call, not two, several times a step);
        None for an agent not queried."""
        client = self.client
        return None if client is None else client.estimator.offset_at(t)


class PeerTable:
    """The peers of ``owner`` (an agent), their links and the sync schedule."""

    def __init__(self, owner: AgentServices):
        self.owner = owner
        cfg = owner.config
        self.peers: dict[AgentId, Peer] = {}
        self.lock = threading.Lock()  # the peers, their links, the pairwise set
        self.explicit_sync = {AgentId.parse(a) for a in cfg.sync_with}
        if self.explicit_sync and owner.follow:
            self.explicit_sync.add(owner.follow)
        # Queried every sync_period; every other agent alive only every
        # sync_others_period, so a leader's load does not grow tenfold with N.
        self.close_sync = self.explicit_sync or {
            a for a in (owner.reference, owner.follow) if a is not None and a != owner.me
        }
        self.sync_all = cfg.sync_all or owner.reference == owner.me
        self.pairwise: set[AgentId] = set()  # senders of poses without our reference stamp
        # The latest stamped pose of each peer: (its t, t_ref, bound).
        self.latest_ref: dict[AgentId, tuple[float, float, float]] = {}
        self.next_sync_due = 0.0  # host monotonic: no peer is due before it
        self.silence = SilenceWatch()  # peers alive that answer no sync request
        self._silent_warned: set[str] = set()  # peers' names

    @property
    def config(self) -> AgentConfig:
        return self.owner.config

    # -- who is queried --------------------------------------------------------------
    def targets(self) -> list[AgentId] | set[AgentId]:
        """The agents this one queries: those in ``sync_with`` (or, when it is empty,
        the reference and the followed agent), senders of poses without its reference
        stamp, and with ``sync_all`` (or on the reference) every other agent seen, in
        the order seen."""
        if self.explicit_sync:
            return self.explicit_sync | self.pairwise
        if self.sync_all:
            return list(self.peers)  # liveliness may add one meanwhile
        return self.close_sync | self.pairwise

    def queries(self, agent: AgentId) -> bool:
        """Whether this agent queries ``agent``."""
        if agent in self.pairwise:
            return True
        if self.explicit_sync:
            return agent in self.explicit_sync
        return self.sync_all or agent in self.close_sync

    def client_of(self, agent: AgentId) -> SyncClient | None:
        """The sync client of ``agent``'s link (None: not seen, or not queried)."""
        peer = self.peers.get(agent)
        return None if peer is None else peer.client

    # -- news ------------------------------------------------------------------------
    def seen(self, agent: AgentId, alive: bool) -> bool:
        """Liveliness news of ``agent``: joined (``alive``) or left. True if it was
        known and its state changed (its poses and contest are to be forgotten)."""
        with self.lock:
            peer = self.peers.get(agent)
            changed = peer is not None and peer.alive != alive
            if peer is None:
                if not alive:
                    return False
                peer = self.peers[agent] = Peer(agent, index=len(self.peers))
                if self.queries(agent):
                    self._attach(peer)
            elif alive and not peer.alive:
                self.silence.forget(agent)
                link = peer.link
                if link is not None:
                    link.reset()  # a restarted agent has a new clock
                    link.next_sync = self._first_sync(peer)
            peer.alive = alive
            self.next_sync_due = 0.0  # due_for_sync looks again
        return changed

    def place(self, agent: AgentId, t: float, stamp: wire.RefStamp | None) -> None:
        """Remember where a peer's pose stamped ``t`` sits on reference time; a sender
        that does not stamp on this agent's reference is synced with pairwise."""
        if stamp is None:
            self.latest_ref.pop(agent, None)
            if agent != self.owner.me and agent not in self.pairwise:
                with self.lock:
                    self.pairwise.add(agent)
                    peer = self.peers.get(agent)  # not seen yet: linked when it is
                    if peer is not None and peer.link is None:
                        self._attach(peer)
                    self.next_sync_due = 0.0
                log.info("%s sends no reference stamp: synced pairwise", agent)
        elif stamp.t_ref is not None and stamp.bound is not None:
            self.latest_ref[agent] = (t, stamp.t_ref, stamp.bound)
        else:  # a stamping sender not yet synchronized: not placed until it is
            self.latest_ref.pop(agent, None)

    def look_again(self) -> None:
        """Look for due peers at the next request (a link lost its sender)."""
        self.next_sync_due = 0.0

    # -- the schedule ----------------------------------------------------------------
    def due_for_sync(self, now: float) -> list[AgentId]:
        """The agents due for a sync request at host monotonic time ``now``, each
        scheduled for its next one: those in ``sync_with`` (or, when it is empty, the
        reference and the followed agent) every ``sync_period``; senders of poses
        without this agent's reference stamp, and with ``sync_all`` (or on the
        reference) every other agent alive, every ``sync_others_period`` on its own
        phase. Walks only those agents, and none before the earliest is due."""
        if now < self.next_sync_due:
            return []
        due: list[AgentId] = []
        earliest = math.inf
        for agent in self.targets():
            peer = self.peers.get(agent)
            link = None if peer is None or not peer.alive else peer.link
            if link is None:  # gone, or not attached yet (pairwise as of now)
                continue
            earliest = min(earliest, self._schedule(agent, link, now, due))
        self.next_sync_due = earliest
        return due

    def _schedule(self, agent: AgentId, link: SyncLink, now: float, due: list[AgentId]) -> float:
        """Append ``agent`` to ``due`` if its link is due at ``now`` and this agent
        sends on it; when to look at it next."""
        cfg = self.config
        close = agent in self.close_sync
        if link.sender is not self.owner:
            # Another agent on this clock queries it for all; taken over if it has
            # not for two periods (it left, or its loop ended before this one's).
            stalled = link.next_sync + 2 * (cfg.sync_period if close else cfg.sync_others_period)
            if not self.owner.links.claim(link, self.owner, stalled <= now):
                return stalled
        if link.next_sync <= now:
            if close:
                link.next_sync = now + 0.5 * cfg.sync_period  # due again at the next tick
            else:
                link.next_sync = next_tick(link.next_sync, cfg.sync_others_period, now)
            due.append(agent)
        return link.next_sync

    def send_sync_requests(self, now: float | None = None) -> None:
        """Query every agent due at host monotonic ``now`` (default: the present), for
        every agent on the same link (each one's silence watch counts the request)."""
        owner = self.owner
        for agent in self.due_for_sync(time.monotonic() if now is None else now):
            link = self.peers[agent].link
            assert link is not None  # due_for_sync gives only agents with a link
            try:
                if link.querier is None:  # one per link: a query costs a single call
                    link.querier = SyncQuerier(
                        owner.session, link.key, self.config.sync_timeout, owner.clock.read,
                        functools.partial(on_link_answer, link),
                    )  # fmt: skip
                with link.lock:
                    payload = link.client.request(owner.clock.now())
                link.querier.request(payload)
                host = time.monotonic()
                for user in link.agents:
                    user.sync_requested(agent, host)
            except Exception as error:  # session closing, or zenoh refusing the query
                log.warning("sync request to %s failed: %s", agent, error)

    # -- links -----------------------------------------------------------------------
    def _first_sync(self, peer: Peer) -> float:
        """When ``peer`` gets its first request (again, after a restart): at once for the
        ones synced every period, else spread over ``sync_others_period`` by the order
        it was seen (golden-ratio phases, so no tick carries a burst however many agents
        join or come back together)."""
        if peer.agent in self.close_sync:
            return 0.0
        phase = (peer.index * _GOLDEN) % 1.0
        return time.monotonic() + phase * self.config.sync_others_period

    def _attach(self, peer: Peer) -> None:
        """Give ``peer`` its sync link (under :attr:`lock`): this agent queries it now."""
        link = self._link_for(peer.agent)
        if link.sharing == 1:  # a new link: this agent schedules its first request
            # Its own phase, from when it was seen: senders that turn pairwise together
            # are not all queried on one tick.
            link.next_sync = self._first_sync(peer)
        peer.attach(link)

    def _link_for(self, agent: AgentId) -> SyncLink:
        """The sync link to ``agent``: shared with the agents of this session that read
        the same clock object and query ``agent`` alike (:mod:`federation.runtime.links`);
        its own for an agent it queries pairwise (its poses carry no stamp on this
        agent's reference) or on a clock that a rehearsal steps."""
        owner, cfg = self.owner, self.config
        close = agent in self.close_sync
        queried = close or (self.sync_all and not self.explicit_sync)
        share: tuple[Any, ...] = (owner, agent)
        if queried and cfg.clock_step is None:
            period = cfg.sync_period if close else cfg.sync_others_period
            share = (
                owner.clock, agent, cfg.federation, period, cfg.estimator, cfg.sync_window,
                cfg.sync_timeout, cfg.four_timestamps,
            )  # fmt: skip
        return owner.links.join(
            owner,
            share,
            lambda: SyncLink(
                agent, owner.key(agent, "sync"), self._new_client(),
                four_timestamps=cfg.four_timestamps,
            ),
        )  # fmt: skip

    def _new_client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), timeout=cfg.sync_timeout)

    # -- what status says ------------------------------------------------------------
    def views(self, t_exec: float, host: float) -> dict[str, PeerStatus]:
        """The figures of every peer queried that has been sent a request: only the
        agents it queries can have figures (a follower among 256 agents queries one or
        two of them), not a walk of every agent seen."""
        views: dict[str, PeerStatus] = {}
        targets = self.targets()
        with self.lock:
            for agent in targets if isinstance(targets, list) else sorted(targets, key=str):
                peer = self.peers.get(agent)
                link = None if peer is None else peer.link  # attached under this lock
                if peer is not None and link is not None and link.client.sent:
                    with link.lock:  # a reply may be changing it on another thread
                        view = views[str(agent)] = peer_status(
                            link.client, t_exec, peer.alive, sharing=link.sharing
                        )
                    view.silent = self.silence.silent_for(agent, host) if peer.alive else None
        return views

    def warn_silent(self, status: Status) -> None:
        """Log once when a peer alive answers nothing (a link that carries liveliness but
        not queries), and once when it answers again."""
        for name, view in status.peers.items():
            if view.silent is not None and name not in self._silent_warned:
                self._silent_warned.add(name)
                self.owner.count(Count.SILENT_PEER_ALARMS)
                log.warning("%s is alive but answered nothing for %.1f s", name, view.silent)
            elif view.silent is None and name in self._silent_warned:
                self._silent_warned.discard(name)
                log.info("%s answers again", name)

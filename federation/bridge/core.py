r"""The UDP bridge's protocol logic, free of I/O: bytes and the bridge's clock go in,
bytes to send and decisions come out.

Nothing here reads a clock, touches a socket or a Zenoh session, or starts a thread;
:mod:`federation.bridge.udp` moves the bytes and makes one call at a time (it holds one
lock around every call), as h11 and aioquic leave I/O to their callers. A test can so
replay any timeline exactly.

Rules this module keeps
-----------------------
Clocks
    ``now`` is always the bridge's own clock. Two sync links estimate offsets from it:
    :math:`\theta_L`, the legacy agent's clock minus the bridge's (the bridge's UDP
    requests), and :math:`\theta_R`, the reference agent's clock minus the bridge's
    (Zenoh queries). A leader bridge's reference is the legacy agent: :math:`\theta_R =
    \theta_L`.
The legacy agent's request (8 bytes, its ``t1``)
    gets a 64-byte reply with the reference clock and the followed agent's pose,

    .. math:: t_2 = t_{now} + \theta_R,

    so its own Eq. 4, :math:`t_2 - (t_1 + t_3)/2`, gives the reference clock minus its
    own. No reply until :math:`\theta_R` is known (as for a lost packet).
The legacy agent's reply (64 bytes) to the bridge's request
    is one exchange of the legacy link (Eq. 3, 4), and its pose sample, stamped with the
    reply's ``t2`` (the legacy agent's clock), to publish.
A federation agent's sync request
    is answered on the legacy agent's behalf: :math:`t_2 = t_{now} + \theta_L` and the
    legacy agent's pose; no reply while :math:`\theta_L` is unknown.
Loss
    No accepted reply for ``legacy_timeout`` seconds: the legacy agent is gone, its
    estimate and pose forgotten (it may come back with a restarted clock).
Reference of a follower bridge without ``follow``
    The first agent by name whose status says ``role: leader``, once no live reference
    is followed. A reference whose liveliness token comes back after going away has a
    new clock: its link starts afresh.
Anything malformed is dropped and counted in ``counters``.
Its name taken
    Another process answers for the legacy agent's name (:meth:`BridgeCore.hold_for_name`):
    for good, the bridge no longer speaks for it. The legacy agent's requests get no
    reply (no reference time, no pose to steer by), its replies are not published, the
    federation's sync queries are not answered, its liveliness token stays away, and
    status says ``hold: name_taken``.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass
from typing import NamedTuple

from federation.core import keys, wire
from federation.core.estimators import make_estimator
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.status import peer_status
from schemas.bridge import UdpBridgeConfig
from schemas.messages import PeerStatus, Status

__all__ = ["BridgeCore", "Maintenance", "Outcome"]


class Outcome(NamedTuple):
    """What a datagram from the legacy side led to."""

    reply: bytes | None = None  # send back to the datagram's source
    pose: bytes | None = None  # publish as the legacy agent's pose sample
    rejected: str | None = None  # why it was dropped, for the log
    kind: str | None = None  # what was dropped: "malformed", "unsynced", "sync reply", "held"


class Maintenance(NamedTuple):
    """What :meth:`BridgeCore.maintain` found; the caller acts on it."""

    legacy_alive: bool  # hold the legacy agent's liveliness token while true
    rejoined: AgentId | None = None  # the reference came back: its old clock is forgotten
    follow: AgentId | None = None  # the new reference: query its sync key, take its pose
    leaders: tuple[AgentId, ...] = ()  # several leaders, said once: ``follow`` is the first


@dataclass
class _Link:
    client: SyncClient
    alive: bool = False
    last_seen: float = -math.inf  # bridge clock of the last accepted exchange


class BridgeCore:
    """The state of one bridge: its two sync links, the latest poses, the agents seen.

    Not thread-safe: the caller serializes calls. Every method is quick.
    """

    def __init__(self, config: UdpBridgeConfig):
        self.config = config
        self.me = config.me
        self.legacy = _Link(self._client())
        self.reference_id: AgentId | None = self.me if config.role == "leader" else config.followed
        self.reference = _Link(self._client())
        self.legacy_pose: wire.PoseSample | None = None  # stamped on the legacy agent's clock
        self.followed_pose: wire.PoseSample | None = None  # stamped on the followed agent's
        self.counters: Counter[str] = Counter()
        self._leaders: set[AgentId] = set()  # agents whose status says role "leader"
        self._alive: set[AgentId] = set()  # agents whose liveliness token is present
        self._seen_gone: set[AgentId] = set()  # agents whose token went away
        self._rejoined = False  # the reference's token came back: a new clock
        self._leaders_said = False
        self.name_clash: str | None = None  # why the bridge no longer speaks for the name

    def hold_for_name(self, detail: str) -> bool:
        """Another process runs under the legacy agent's name: stop speaking for it, for
        good (which of the two is genuine cannot be told in-band). True the first time."""
        if self.name_clash is not None:
            return False
        self.name_clash = detail
        self.counters["name_taken_holds"] += 1
        return True

    def name_alive_elsewhere(self) -> bool:
        """Whether the legacy agent's name has a liveliness token while the bridge holds
        none for it (asked before it declares its own)."""
        return self.me in self._alive

    def _client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), cfg.sync_timeout)

    def count(self, name: str) -> None:
        """Count an event the caller saw (a send error, a foreign datagram, ...)."""
        self.counters[name] += 1

    # -- clocks ----------------------------------------------------------------------
    def legacy_offset(self, now: float) -> float | None:
        """Legacy agent's clock minus the bridge's; None until it answers (or once lost)."""
        return self.legacy.client.offset_at(now) if self.legacy.alive else None

    def reference_offset(self, now: float) -> float | None:
        """Reference agent's clock minus the bridge's (Eq. 5's offset, via the bridge)."""
        if self.config.role == "leader":
            return self.legacy_offset(now)
        if self.reference_id is None:
            return None
        return self.reference.client.offset_at(now)

    # -- the legacy side (UDP) ---------------------------------------------------------
    def legacy_request(self, now: float) -> bytes:
        """The bridge's own 8-byte request to the legacy agent, sent at ``now``."""
        self.counters["udp_requests_sent"] += 1
        return self.legacy.client.request(now)

    def on_datagram(self, data: bytes, now: float) -> Outcome:
        """A datagram from the legacy agent, read at ``now``: its request (8 bytes) or its
        reply to ours (64 bytes)."""
        if self.name_clash is not None:
            self.counters["udp_held_for_name"] += 1
            return Outcome(rejected=f"not speaking for {self.me}: {self.name_clash}", kind="held")
        if len(data) == wire.REQUEST_SIZE:
            return self._on_legacy_request(data, now)
        if len(data) == wire.REPLY_SIZE:
            return self._on_legacy_reply(data, now)
        self.counters["udp_malformed"] += 1
        sizes = f"{wire.REQUEST_SIZE} or {wire.REPLY_SIZE}"
        return Outcome(rejected=f"expected {sizes} bytes, got {len(data)}", kind="malformed")

    def _on_legacy_request(self, data: bytes, now: float) -> Outcome:
        try:
            t1 = wire.decode_request(data)
        except wire.DecodeError as error:
            self.counters["udp_malformed"] += 1
            return Outcome(rejected=str(error), kind="malformed")
        offset = self.reference_offset(now)
        if offset is None:
            self.counters["udp_requests_unsynced"] += 1
            return Outcome(rejected="no reference time yet", kind="unsynced")
        pose = self.followed_pose.pose if self.followed_pose else wire.Pose()
        self.counters["udp_requests_served"] += 1
        # t2 on the reference clock: the legacy agent's Eq. 4 then gives leader minus itself.
        return Outcome(reply=wire.encode_reply(t1, now + offset, pose))

    def _on_legacy_reply(self, data: bytes, now: float) -> Outcome:
        link = self.legacy
        reply = link.client.receive(data, now)
        if reply is None:
            reason = link.client.last_rejection or "rejected"
            if reason == "malformed":
                self.counters["udp_malformed"] += 1
            kind = "malformed" if reason == "malformed" else "sync reply"
            return Outcome(rejected=f"sync reply ({reason})", kind=kind)
        if not link.alive:
            link.alive = True
            self.counters["legacy_found"] += 1
        link.last_seen = now
        link.client.offset_at(now)  # fit now, so a query's t2 costs no regression
        self.legacy_pose = wire.PoseSample(reply.t2, reply.pose)
        self.counters["pose_published"] += 1
        return Outcome(pose=wire.encode_pose(reply.t2, reply.pose))

    def check_legacy(self, now: float) -> bool:
        """Whether the legacy agent is answering; after ``legacy_timeout`` without an
        accepted reply it is lost and its estimate forgotten (it may come back with a
        restarted clock)."""
        link = self.legacy
        if link.alive and now - link.last_seen > self.config.legacy_timeout:
            link.alive = False
            link.client.reset()
            self.legacy_pose = None
            self.counters["legacy_lost"] += 1
        return link.alive

    # -- the federation side (Zenoh) ---------------------------------------------------
    def on_sync_query(self, payload: bytes, now: float) -> tuple[bytes, float] | None:
        """A federation agent's sync request arriving at ``now``: the 64-byte reply on the
        legacy agent's behalf and the legacy offset it used (to stamp the send time on
        the legacy clock), or None (no reply; none either once the name is taken
        elsewhere). Raises wire.DecodeError if malformed."""
        if self.name_clash is not None:
            self.counters["sync_requests_held"] += 1
            return None
        try:
            t1 = wire.decode_request(payload)
        except wire.DecodeError:
            self.counters["sync_requests_malformed"] += 1
            raise
        offset = self.legacy_offset(now)
        if offset is None:
            self.counters["sync_requests_unsynced"] += 1
            return None
        pose = self.legacy_pose.pose if self.legacy_pose else wire.Pose()
        self.counters["sync_requests_served"] += 1
        return wire.encode_reply(t1, now + offset, pose), offset

    def reference_request(self, now: float) -> bytes | None:
        """The next sync request to the reference agent (None for a leader bridge)."""
        if self.config.role == "leader" or self.reference_id is None:
            return None
        return self.reference.client.request(now)

    def on_reference_reply(self, payload: bytes, now: float, t2s: float | None = None) -> bool:
        """The reference's reply read at ``now``; False if rejected (the reason is
        ``reference.client.last_rejection``)."""
        link = self.reference
        if link.client.receive(payload, now, t2s) is None:
            return False
        link.last_seen = now
        link.client.offset_at(now)  # fit now, off the legacy agent's request path
        return True

    def on_followed_pose(self, payload: bytes) -> None:
        """A pose sample of the followed agent. Raises wire.DecodeError if malformed."""
        try:
            sample = wire.decode_pose(payload)
        except wire.DecodeError:
            self.counters["pose_malformed"] += 1
            raise
        self.followed_pose = sample
        self.counters["pose_received"] += 1

    def on_status(self, payload: bytes) -> None:
        """An agent's status line (JSON): notes the agents that say they lead."""
        try:
            status = json.loads(payload)
            if status.get("role") == "leader":
                self._leaders.add(AgentId.parse(str(status["agent"])))
        except (ValueError, KeyError, TypeError, AttributeError):
            pass  # a malformed status is the monitor's business

    def on_liveliness(self, key: str, alive: bool) -> None:
        """An agent's liveliness token came (``alive``) or went; other keys are ignored."""
        parsed = keys.parse_agent_key(self.config.federation, key)
        if parsed is None or parsed[1] is not None:
            return
        agent = parsed[0]
        if agent == self.reference_id:
            self.reference.alive = alive
        if alive:
            if agent == self.reference_id and agent not in self._alive:
                self._rejoined = agent in self._seen_gone
            self._alive.add(agent)
        else:
            self._alive.discard(agent)
            self._leaders.discard(agent)
            self._seen_gone.add(agent)

    def maintain(self, now: float) -> Maintenance:
        """Every sync period: is the legacy agent still answering, has the reference
        rejoined, and (a follower without ``follow``) which leader to follow."""
        legacy_alive = self.check_legacy(now) and self.name_clash is None
        if self.config.role != "follower":
            return Maintenance(legacy_alive)
        rejoined, self._rejoined = self._rejoined, False
        current = self.reference_id
        found = None
        if rejoined and current is not None:
            self._sync_afresh(current)
            found = current
        leaders = sorted(self._leaders - {self.me})
        if self.config.follow is not None or current in self._alive or not leaders:
            return Maintenance(legacy_alive, found)
        if current in leaders:
            return Maintenance(legacy_alive, found)  # its status arrives: its token will too
        several: tuple[AgentId, ...] = ()
        if len(leaders) > 1 and not self._leaders_said:
            several, self._leaders_said = tuple(leaders), True
        self._sync_afresh(leaders[0])
        return Maintenance(legacy_alive, found, leaders[0], several)

    def _sync_afresh(self, agent: AgentId) -> None:
        """Sync with ``agent`` afresh from now on (found by its status, or rejoined with
        a new clock)."""
        self.reference_id = agent
        self.reference = _Link(self._client(), agent in self._alive)
        self.followed_pose = None

    # -- status ------------------------------------------------------------------------
    def status(self, now: float, host: float) -> Status:
        """Status at bridge clock ``now`` (``host``: the host clock read with it), on the
        legacy agent's clock once it is known."""
        cfg = self.config
        legacy = self.legacy_offset(now)
        base = 0.0 if legacy is None else legacy
        ref = self.reference_offset(now)
        peers = {}
        if cfg.role == "follower" and self.reference_id is not None:
            peers[str(self.reference_id)] = _peer_status(self.reference, now, base)
        link = _peer_status(self.legacy, now, 0.0).model_dump()
        pose = list(self.legacy_pose.pose) if self.legacy_pose else list(wire.Pose())
        follow = cfg.followed if cfg.role == "leader" else self.reference_id
        pose_age = None
        if self.followed_pose is not None and cfg.role == "follower" and ref is not None:
            pose_age = now + ref - self.followed_pose.t  # its samples are on its clock
        return Status(
            agent=cfg.agent,
            federation=cfg.federation,
            role=cfg.role,
            reference=str(self.reference_id or self.me),
            t_exec=now + base,
            host_monotonic=host,
            t_sim=None if ref is None else now + ref,
            mode="unmanaged",
            platform=f"udp:{cfg.peer_text}",
            follow=None if follow is None else str(follow),
            hold=None if self.name_clash is None else "name_taken",
            pose_age=pose_age,
            pose=pose,
            peers=peers,
            counters=dict(self.counters),
            clock="bridge" if legacy is None else "legacy",
            legacy={"address": cfg.peer_text, "bridge_t_exec": now, **link},
        )


def _peer_status(link: _Link, now: float, base: float) -> PeerStatus:
    """A link's view as in every agent's status; ``base``: the status clock minus the
    bridge's, so the offset is relative to the clock ``t_exec`` is on."""
    return peer_status(link.client, now, link.alive, base)

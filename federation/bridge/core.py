r"""The UDP bridge's protocol logic, free of I/O: bytes and the bridge's clock go in,
bytes to send and decisions come out.

Nothing here reads a clock, touches a socket or a Zenoh session, or starts a thread;
:mod:`federation.bridge.udp` moves the bytes and makes one call at a time (it holds one
lock around every call), as h11 and aioquic leave I/O to their callers. A test can so
replay any timeline exactly.

Rules this module keeps
-----------------------
Who is heard on UDP
    Only ``--peer``'s host (``udp_foreign`` otherwise). Its replies only from ``--peer``
    itself, address and port: the bridge's requests go there, a legacy agent answers
    from the socket they reach (the paper's channel: one pair of ports), and a stateful
    firewall in front of the bridge lets in that one flow only
    (``udp_replies_foreign_port``), or, with ``reply_port``, from that port of its host
    (an agent that answers from another socket). Its requests from any
    port of that host (the paper's second channel), or, with ``request_port``, from that
    port only (``udp_requests_foreign_port``). UDP carries no proof of its source: the
    pin narrows who can forge a request to whoever can forge that host's address and
    port, and keeps others' requests from spending the rate limit below.
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
    own. No reply (as for a lost packet: the legacy agent's own design fails closed on
    it) until :math:`\theta_R` is known, and none while there is nothing safe to steer
    by: no followed pose yet, one older than ``stale_after`` (on the followed agent's
    clock, and since it arrived), a reference gone or contested, or a ``fedlab ctl
    abort`` until ``reset``. A request carrying one of the bridge's own ``t1`` (its own
    request come back: ``--peer`` is the bridge itself) is dropped (``udp_self``).
    At most ``request_burst`` requests are answered at once and ``request_rate_limit``
    a second on average (a token bucket, :class:`TokenBucket`); those over it are
    dropped (``udp_rate_limited``). A forged request (its source is not checked by UDP)
    draws a 64-byte reply for 8 bytes and the followed pose: the limit bounds that
    amplifier. The legacy agent's replies need no limit: each is matched to one of the
    bridge's own requests (one every ``sync_period``), at most once, and draws nothing.
The legacy agent's reply (64 bytes) to the bridge's request
    is one exchange of the legacy link (Eq. 3, 4), and its pose sample, stamped with the
    reply's ``t2`` (the legacy agent's clock), to publish once the exchange has reached
    the estimate (not held back by the warm-up, not a wild one) and is newer than the
    last published. A clock step of the legacy agent (it restarted) is counted
    (``legacy_restarted``); the agents' own sync with it sees the step too, forgets
    the order of its poses and, where it is their reference, ends a ctl run.
A federation agent's sync request
    is answered on the legacy agent's behalf: :math:`t_2 = t_{now} + \theta_L` and the
    legacy agent's pose; no reply while :math:`\theta_L` is unknown.
Loss
    No accepted reply for ``legacy_timeout`` seconds: the legacy agent is gone, its
    estimate and pose forgotten (it may come back with a restarted clock).
The followed agent's poses and the reference's replies
    only from its key; two sources speaking for it (sessions) contest it, as for every
    agent (:class:`~federation.core.contest.ContestWatch`): nothing from it is used and
    the reference link restarts; a pose no newer than the last from its source is
    dropped (:func:`~federation.core.contest.in_order`).
Execution control
    A ``fedlab ctl abort`` (honoured whatever its issuer or seq, even malformed) holds
    the legacy agent (no replies) until a ``reset``; status ``mode`` and ``hold`` say
    ``aborted``, so ctl sees it confirmed. Other commands are ignored: a legacy agent
    runs its own timeline (``mode: unmanaged``).
Reference of a follower bridge without ``follow``
    The first agent by name, alive, whose status (on its own key) says ``role:
    leader``, once no live reference is followed. A reference whose liveliness token
    comes back after going away has a new clock: its link starts afresh.
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
from collections import Counter, deque
from dataclasses import dataclass
from typing import NamedTuple

from pydantic import ValidationError

from federation.core import keys, wire
from federation.core.commands import CommandGate
from federation.core.contest import ContestWatch, in_order
from federation.core.counters import Count
from federation.core.estimators import make_estimator
from federation.core.holds import Hold
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.status import peer_status
from schemas.bridge import UdpBridgeConfig, format_address
from schemas.messages import (
    Command,
    CommandOutcome,
    PeerStatus,
    Status,
    is_abort,
    malformed_outcome,
    validation_reason,
)

__all__ = ["BridgeCore", "Maintenance", "Outcome", "TokenBucket"]

_MAX_LEADERS = 256
"""Agents remembered as saying they lead (a flood of statuses cannot grow the bridge)."""


class Outcome(NamedTuple):
    """What a datagram from the legacy side led to."""

    reply: bytes | None = None  # send back to the datagram's source
    pose: bytes | None = None  # publish as the legacy agent's pose sample
    rejected: str | None = None  # why it was dropped, for the log
    # What was dropped: "foreign", "malformed", "unsynced", "sync reply", "held", "self",
    # "rate limited".
    kind: str | None = None


class Maintenance(NamedTuple):
    """What :meth:`BridgeCore.maintain` found; the caller acts on it."""

    legacy_alive: bool  # hold the legacy agent's liveliness token while true
    rejoined: AgentId | None = None  # the reference came back: its old clock is forgotten
    follow: AgentId | None = None  # the new reference: query its sync key, take its pose
    leaders: tuple[AgentId, ...] = ()  # several leaders, said once: ``follow`` is the first


class TokenBucket:
    """At most ``burst`` events at once and ``rate`` a second on average.

    Holds up to ``burst`` tokens, starts full and gains ``rate`` a second; an event takes
    one, or is refused when none is left. Time is passed in; a clock that goes back
    mints none.
    """

    _SLACK = 1e-9  # tokens: an event exactly one period after the last is not refused

    def __init__(self, rate: float, burst: int):
        self.rate, self.burst = rate, burst
        self.tokens = float(burst)
        self._last: float | None = None

    def take(self, now: float) -> bool:
        """Whether an event at ``now`` is allowed (a token taken if so)."""
        if self._last is None or now > self._last:
            if self._last is not None:
                self.tokens = min(float(self.burst), self.tokens + (now - self._last) * self.rate)
            self._last = now
        if self.tokens < 1.0 - self._SLACK:
            return False
        self.tokens = max(0.0, self.tokens - 1.0)
        return True


@dataclass
class _Link:
    client: SyncClient
    alive: bool = False
    last_seen: float = -math.inf  # bridge clock of the last accepted exchange


class BridgeCore:
    """The state of one bridge: its two sync links, the latest poses, the agents seen.

    Not thread-safe: the caller serializes calls. Every method is quick.
    """

    def __init__(self, config: UdpBridgeConfig, peer: tuple[str, int] | None = None):
        """``peer``: ``--peer`` resolved, as datagrams from it give their source (None:
        ``config.peer_address`` as written, a numeric address)."""
        self.config = config
        self.peer = peer if peer is not None else config.peer_address
        self._reply_port = config.reply_port or self.peer[1]  # where replies may come from
        self.requests = TokenBucket(config.request_rate_limit, config.request_burst)
        self.me = config.me
        self.legacy = _Link(self._client())
        self.reference_id: AgentId | None = self.me if config.role == "leader" else config.followed
        self.reference = _Link(self._client())
        self.legacy_pose: wire.PoseSample | None = None  # stamped on the legacy agent's clock
        self.followed_pose: wire.PoseSample | None = None  # stamped on the followed agent's
        self.counters: Counter[Count] = Counter()
        self._leaders: set[AgentId] = set()  # agents whose status says role "leader"
        self._alive: set[AgentId] = set()  # agents whose liveliness token is present
        self._seen_gone: set[AgentId] = set()  # agents whose token went away
        self._rejoined = False  # the reference's token came back: a new clock
        self._leaders_said = False
        self.name_clash: str | None = None  # why the bridge no longer speaks for the name
        self.aborted = False  # fedlab ctl abort, until a reset: the legacy agent held
        self.gate = CommandGate()
        self.commands: deque[CommandOutcome] = deque(maxlen=8)
        self.contest = ContestWatch()  # who speaks for the followed agent
        self._order: dict[AgentId, tuple[str | None, float]] = {}
        self.followed_at: float | None = None  # bridge clock when the followed pose came
        self._legacy_steps = 0  # the legacy link's clock steps seen

    def hold_for_name(self, detail: str) -> bool:
        """Another process runs under the legacy agent's name: stop speaking for it, for
        good (which of the two is genuine cannot be told in-band). True the first time."""
        if self.name_clash is not None:
            return False
        self.name_clash = detail
        self.counters[Count.NAME_TAKEN_HOLDS] += 1
        return True

    def name_alive_elsewhere(self) -> bool:
        """Whether the legacy agent's name has a liveliness token while the bridge holds
        none for it (asked before it declares its own)."""
        return self.me in self._alive

    @property
    def followed_id(self) -> AgentId | None:
        """The agent whose pose the legacy agent receives: the reference of a follower
        bridge, ``follow`` of a leader bridge (None: none)."""
        return self.reference_id if self.config.role == "follower" else self.config.followed

    @property
    def _peer_text(self) -> str:
        """``--peer`` as written, and as resolved where that differs."""
        written, resolved = self.config.peer_text, format_address(self.peer)
        return written if resolved == written else f"{written} ({resolved})"

    def _client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), cfg.sync_timeout)

    def count(self, name: Count) -> None:
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
        self.counters[Count.UDP_REQUESTS_SENT] += 1
        return self.legacy.client.request(now)

    def on_datagram(self, data: bytes, source: tuple[str, int], now: float) -> Outcome:
        """A datagram from ``source`` (host, port), read at ``now``: the legacy agent's
        request (8 bytes) or its reply to ours (64 bytes)."""
        host, port = source
        if host != self.peer[0]:
            self.counters[Count.UDP_FOREIGN] += 1
            return Outcome(
                rejected=f"not the legacy agent's host (--peer {self._peer_text})", kind="foreign"
            )
        if self.name_clash is not None:
            self.counters[Count.UDP_HELD_FOR_NAME] += 1
            return Outcome(rejected=f"not speaking for {self.me}: {self.name_clash}", kind="held")
        if len(data) == wire.REQUEST_SIZE:
            pinned = self.config.request_port
            if pinned is not None and port != pinned:
                self.counters[Count.UDP_REQUESTS_FOREIGN_PORT] += 1
                said = f"a request from port {port}: taken from --request-port {pinned} only"
                return Outcome(rejected=said, kind="foreign")
            return self._on_legacy_request(data, now)
        if len(data) == wire.REPLY_SIZE:
            if port != self._reply_port:
                self.counters[Count.UDP_REPLIES_FOREIGN_PORT] += 1
                said = f"a reply from port {port}: taken from " + (
                    f"--reply-port {self.config.reply_port} only"
                    if self.config.reply_port
                    else f"--peer {self._peer_text} only, where the bridge's requests go"
                )
                return Outcome(rejected=said, kind="foreign")
            return self._on_legacy_reply(data, now)
        self.counters[Count.UDP_MALFORMED] += 1
        sizes = f"{wire.REQUEST_SIZE} or {wire.REPLY_SIZE}"
        return Outcome(rejected=f"expected {sizes} bytes, got {len(data)}", kind="malformed")

    def _on_legacy_request(self, data: bytes, now: float) -> Outcome:
        try:
            t1 = wire.decode_request(data)
        except wire.DecodeError as error:
            self.counters[Count.UDP_MALFORMED] += 1
            return Outcome(rejected=str(error), kind="malformed")
        if self.legacy.client.sent_here(t1):
            self.counters[Count.UDP_SELF] += 1
            return Outcome(rejected="the bridge's own request came back (--peer)", kind="self")
        if self.aborted:
            self.counters[Count.UDP_REQUESTS_HELD] += 1
            return Outcome(rejected="aborted (fedlab ctl reset releases it)", kind="held")
        offset = self.reference_offset(now)
        if offset is None:
            self.counters[Count.UDP_REQUESTS_UNSYNCED] += 1
            return Outcome(rejected="no reference time yet", kind="unsynced")
        why = self._nothing_to_steer_by(now, offset)
        if why is not None:
            self.counters[why[0]] += 1
            return Outcome(rejected=why[1], kind="held")
        # Last: only a request that would be answered spends a token.
        if not self.requests.take(now):
            self.counters[Count.UDP_RATE_LIMITED] += 1
            cfg = self.config
            said = (
                f"over --request-rate-limit {cfg.request_rate_limit:g}/s "
                f"(--request-burst {cfg.request_burst}): no reply"
            )
            return Outcome(rejected=said, kind="rate limited")
        pose = self.followed_pose.pose if self.followed_pose else wire.Pose()
        self.counters[Count.UDP_REQUESTS_SERVED] += 1
        # t2 on the reference clock: the legacy agent's Eq. 4 then gives leader minus itself.
        return Outcome(reply=wire.encode_reply(t1, now + offset, pose))

    def _nothing_to_steer_by(self, now: float, offset: float) -> tuple[Count, str] | None:
        """Why the followed pose must not reach the legacy agent now (its counter and the
        reason), None if it may; a leader bridge that follows no one sends none."""
        target = self.followed_id
        if target is None:
            return None
        contested = self.contest.reason(str(target), now)
        if contested is not None:
            return Count.UDP_REQUESTS_CONTESTED, f"{target} is contested: {contested}"
        if self.config.role == "follower" and not self.reference.alive:
            return Count.UDP_REQUESTS_REFERENCE_GONE, f"{target} is not in the federation"
        pose, limit = self.followed_pose, self.config.stale_after
        if pose is None or self.followed_at is None:
            return Count.UDP_REQUESTS_NO_POSE, f"no pose of {target} yet"
        since = now - self.followed_at
        # On its clock (a follower's reference is synced): a pose old on arrival counts.
        # The paper's estimators (mean, median) stop at the end of their window while
        # clocks drift apart, so with them the age since arrival alone is judged.
        on_its_clock = self.config.role == "follower" and self.config.estimator == "clockfilter"
        age = now + offset - pose.t if on_its_clock else since
        if max(age, since) > limit:
            return Count.UDP_REQUESTS_STALE, f"{target}'s pose is {max(age, since):.3f} s old"
        return None

    def _on_legacy_reply(self, data: bytes, now: float) -> Outcome:
        link = self.legacy
        reply = link.client.receive(data, now)
        if reply is None:
            reason = link.client.last_rejection or "rejected"
            if reason == "malformed":
                self.counters[Count.UDP_MALFORMED] += 1
            kind = "malformed" if reason == "malformed" else "sync reply"
            return Outcome(rejected=f"sync reply ({reason})", kind=kind)
        if not link.alive:
            link.alive = True
            self.counters[Count.LEGACY_FOUND] += 1
        link.last_seen = now
        if link.client.steps > self._legacy_steps:  # its clock jumped: it restarted
            self._legacy_steps = link.client.steps
            self.legacy_pose = None
            self.counters[Count.LEGACY_RESTARTED] += 1
        link.client.offset_at(now)  # fit now, so a query's t2 costs no regression
        if not link.client.last_fed:
            # Held back by the warm-up until three agree: its t2 is not trusted yet.
            self.counters[Count.POSE_UNCONFIRMED] += 1
            return Outcome(rejected="not yet confirmed by the estimate", kind="sync reply")
        if self.legacy_pose is not None and not reply.t2 > self.legacy_pose.t:
            self.counters[Count.POSE_OUT_OF_ORDER] += 1
            return Outcome(rejected="no newer than the last published", kind="sync reply")
        self.legacy_pose = wire.PoseSample(reply.t2, reply.pose)
        self.counters[Count.POSE_PUBLISHED] += 1
        return Outcome(pose=wire.encode_pose(reply.t2, reply.pose))

    def check_legacy(self, now: float) -> bool:
        """Whether the legacy agent is answering; after ``legacy_timeout`` without an
        accepted reply it is lost and its estimate forgotten (it may come back with a
        restarted clock)."""
        link = self.legacy
        if link.alive and now - link.last_seen > self.config.legacy_timeout:
            link.alive = False
            link.client = self._client()  # it may come back with a restarted clock
            self._legacy_steps = 0
            self.legacy_pose = None
            self.counters[Count.LEGACY_LOST] += 1
        return link.alive

    # -- the federation side (Zenoh) ---------------------------------------------------
    def on_sync_query(self, payload: bytes, now: float) -> tuple[bytes, float] | None:
        """A federation agent's sync request arriving at ``now``: the 64-byte reply on the
        legacy agent's behalf and the legacy offset it used (to stamp the send time on
        the legacy clock), or None (no reply; none either once the name is taken
        elsewhere). Raises wire.DecodeError if malformed."""
        if self.name_clash is not None:
            self.counters[Count.SYNC_REQUESTS_HELD] += 1
            return None
        try:
            t1 = wire.decode_request(payload)
        except wire.DecodeError:
            self.counters[Count.SYNC_REQUESTS_MALFORMED] += 1
            raise
        offset = self.legacy_offset(now)
        if offset is None:
            self.counters[Count.SYNC_REQUESTS_UNSYNCED] += 1
            return None
        pose = self.legacy_pose.pose if self.legacy_pose else wire.Pose()
        self.counters[Count.SYNC_REQUESTS_SERVED] += 1
        return wire.encode_reply(t1, now + offset, pose), offset

    def reference_request(self, now: float) -> bytes | None:
        """The next sync request to the reference agent (None for a leader bridge)."""
        if self.config.role == "leader" or self.reference_id is None:
            return None
        return self.reference.client.request(now)

    def on_reference_reply(
        self, payload: bytes, now: float, t2s: float | None = None, replier: str | None = None
    ) -> bool:
        """The reference's reply read at ``now`` from session ``replier``; False if
        rejected (the reason is ``reference.client.last_rejection``, or ``contested``)."""
        link = self.reference
        if self.reference_id is not None and not self._admitted(
            self.reference_id, "sync", replier, now
        ):
            link.client.last_rejection = "contested"
            return False
        if link.client.receive(payload, now, t2s) is None:
            return False
        link.last_seen = now
        link.client.offset_at(now)  # fit now, off the legacy agent's request path
        return True

    def on_followed_pose(
        self,
        payload: bytes,
        now: float,
        agent: AgentId | None = None,
        source: str | None = None,
    ) -> None:
        """A pose sample on ``agent``'s key (None: the followed agent's) from session
        ``source``, read at ``now``; used only if it is the followed agent's, from its
        one source, and newer than the last. Raises wire.DecodeError if malformed."""
        target = self.followed_id
        if target is None or (agent is not None and agent != target):
            self.counters[Count.POSE_OTHER_AGENT] += 1  # a former reference's, still arriving
            return
        try:
            sample = wire.decode_pose(payload)
        except wire.DecodeError:
            self.counters[Count.POSE_MALFORMED] += 1
            raise
        self.counters[Count.POSE_RECEIVED] += 1
        if not self._admitted(target, "pose", source, now):
            return
        if not in_order(self._order, target, source, sample.t):
            self.counters[Count.POSE_OUT_OF_ORDER] += 1
            return
        self.followed_pose, self.followed_at = sample, now

    def _admitted(self, agent: AgentId, channel: str, source: str | None, now: float) -> bool:
        """Whether ``source`` may speak for ``agent`` (its contest watch); a new contest
        forgets its pose and restarts the reference link."""
        outcome = self.contest.observe(str(agent), channel, source, now)  # type: ignore[arg-type]
        if outcome == "ok":
            return True
        self.counters[Count.CONTESTED_DROPPED] += 1
        if outcome == "contested":
            self.counters[Count.CONTESTED] += 1
            self.followed_pose = self.followed_at = None
            if agent == self.reference_id and self.config.role == "follower":
                self.reference = _Link(self._client(), self.reference.alive)
        return False

    def on_control(self, payload: bytes) -> str | None:
        """A ``fedlab ctl`` command: an abort holds the legacy agent until a reset; others
        are ignored (it runs its own timeline). What was done, for the log (None: a
        repeat or nothing)."""
        try:
            command = Command.model_validate_json(payload)
        except (ValidationError, ValueError) as error:
            self.counters[Count.CONTROL_MALFORMED] += 1
            if not is_abort(payload):
                why = validation_reason(error) if isinstance(error, ValidationError) else str(error)
                reported = malformed_outcome(payload, why)
                if reported is not None:  # ctl says why, not "command not seen"
                    self.commands.append(reported)
                return None
            command = Command(command="abort", seq=-1, issuer="malformed")
        self.counters[Count.CONTROL_RECEIVED] += 1
        verdict = self.gate.admit(command.command, command.issuer, command.seq)
        if not verdict.admitted:
            if verdict.outcome != "repeat":
                self._outcome(command, verdict.outcome, verdict.detail)
            return None
        not_mine = command.not_for(str(self.me))
        if not_mine is not None:
            self._outcome(command, "ignored", not_mine)
            return None
        if command.command == "abort":
            done = "aborted: no replies to the legacy agent until fedlab ctl reset"
            self.aborted = True
        elif command.command == "reset" and self.aborted:
            done, self.aborted = "reset: the legacy agent is answered again", False
        else:
            detail = "a legacy agent runs its own timeline"
            self._outcome(command, "ignored", detail)
            return None
        self._outcome(command, "applied", "")
        return done

    def _outcome(self, command: Command, outcome: str, detail: str) -> None:
        self.commands.append(
            CommandOutcome(
                command=command.command, issuer=command.issuer[:200], seq=command.seq,
                outcome=outcome, detail=detail,
            )
        )  # fmt: skip

    def on_status(self, payload: bytes, agent: AgentId | None = None) -> None:
        """An agent's status line (JSON) on ``agent``'s key: notes the agents that say
        they lead (only of themselves: a status naming another is not taken)."""
        try:
            status = json.loads(payload)
            said = AgentId.parse(str(status["agent"]))
            if agent is not None and said != agent:
                self.counters[Count.STATUS_NOT_ITS_OWN] += 1
                return
            if status.get("role") == "leader" and len(self._leaders) < _MAX_LEADERS:
                self._leaders.add(said)
        except (ValueError, KeyError, TypeError, AttributeError, RecursionError):
            self.counters[Count.STATUS_MALFORMED] += 1  # the monitor's business, counted

    def on_liveliness(self, key: str, alive: bool) -> None:
        """An agent's liveliness token came (``alive``) or went; other keys are ignored."""
        parsed = keys.parse_agent_key(self.config.federation, key)
        if parsed is None or parsed[1] is not None:
            return
        agent = parsed[0]
        if agent == self.reference_id:
            self.reference.alive = alive
        if agent == self.followed_id and (agent in self._alive) != alive:
            self.contest.forget(str(agent))  # a restarted agent has a new session
            self._order.pop(agent, None)  # and may count time afresh
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
        leaders = sorted((self._leaders & self._alive) - {self.me})
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
        self.followed_pose = self.followed_at = None
        self.contest.forget(str(agent))
        self._order.pop(agent, None)

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
            mode="aborted" if self.aborted else "unmanaged",
            platform=f"udp:{cfg.peer_text}",
            follow=None if follow is None else str(follow),
            hold=Hold.NAME_TAKEN if self.name_clash else (Hold.ABORTED if self.aborted else None),
            commands=list(self.commands),
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

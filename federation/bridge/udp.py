"""``fedlab bridge udp``: an unchanged legacy agent that speaks the paper's UDP packets
joins a federation as an agent like any other.

The legacy agent (a Simulink model, say) knows one peer: the bridge's UDP address. It
sends 8-byte requests there and answers the bridge's 8-byte requests with 64-byte
replies (docs/paper.md, paper section 3.2). The bridge translates both directions::

    legacy agent  <--- UDP (paper's packets) --->  bridge  <--- Zenoh --->  federation

Towards the legacy agent
    Its requests get 64-byte replies whose ``t2`` is the federation's reference time
    (the leader's clock: the bridge's clock plus its offset estimate of the leader's,
    kept by 10 Hz sync queries like any agent's) and whose pose is the followed
    agent's latest pose. The legacy agent sees the leader as the paper's peer.

Towards the federation, for ``LAB/NAME``
    The bridge sends its own requests to the legacy agent every 100 ms. Each reply
    gives a sync exchange with the legacy agent's clock (Eq. 3, 4) and its pose,
    published as a 56-byte sample stamped with the reply's ``t2`` (the legacy agent's
    own clock). Sync queries on ``LAB/NAME/sync`` are answered on the legacy agent's
    behalf: ``t2`` is the legacy agent's clock now (the bridge's clock plus its offset
    estimate of the legacy agent's), the pose its latest. The liveliness token is
    present while the legacy agent answers; status is published once a second.

Each hop adds its own estimate's error; on a LAN between bridge and legacy agent that
is tens of microseconds, against the internet path's milliseconds.

Firewall (the paper's way): the UDP socket bound to ``--listen`` sends the first
request to ``--peer`` before anything is expected, so a stateful firewall in front of
the bridge opens the flow for the legacy agent's packets; the requests every
``--sync-period`` are the keepalive that holds it open. One socket carries both
directions: 8-byte datagrams are the legacy agent's requests, 64-byte ones its replies.
Requests are answered to their source, so a legacy agent may use one port or two (the
paper's two channels). Replies are taken from ``--peer`` only, address and port: where
the bridge's requests go, and the one flow that firewall lets in.

Who is answered, and how often (decided in the core)
    UDP does not prove a datagram's source. Whoever can send from the legacy agent's
    host, or forge its address, gets for an 8-byte request a 64-byte reply with the
    followed agent's pose: a leak, and an amplifier aimed at that host. So:

    - datagrams from a host other than ``--peer``'s are dropped (``udp_foreign``);
    - with ``--request-port PORT``, requests are taken from that port of ``--peer``'s
      host only (``udp_requests_foreign_port``). Set it whenever the legacy agent sends
      from a fixed port (``--peer``'s own, if it uses one socket). Unset, as the paper's
      two channels allow, any port of that host is answered: every process there, and
      whoever forges its address, is answered as the legacy agent;
    - at most ``--request-burst`` requests (20) are answered at once and
      ``--request-rate-limit`` (50) a second on average, five times the paper's 10 Hz;
      the rest get no reply (``udp_rate_limited``), which bounds the amplifier (at
      3.2 kB/s by default). The limit is shared: forged requests that pass the checks
      above spend it, and the legacy agent then gets no reply either, which its design
      takes as a lost link (it holds);
    - replies from another port of ``--peer``'s host are dropped
      (``udp_replies_foreign_port``). Replies need no limit: each is matched to one of
      the bridge's own requests (one every ``--sync-period``), at most once, and draws
      nothing back.

A datagram of another size or holding NaN or infinity is dropped too. Every dropped
datagram is logged (rate-limited) and counted in status.

Status (JSON, ``schemas.messages.Status`` plus the bridge's fields)
    ``t_exec`` is the legacy agent's clock as the bridge estimates it (``clock``:
    ``"legacy"``), or the bridge's own clock before the first exchange (``clock``:
    ``"bridge"``); ``peers`` holds the reference agent, its offset relative to that
    clock as for every agent; ``legacy`` holds the UDP link (offset: legacy agent's
    clock minus the bridge's, delay, samples, ...); ``mode`` is ``"unmanaged"``: a
    legacy agent runs its own timeline, and of execution control the bridge takes only
    ``abort`` (no replies to it, ``mode`` and ``hold`` ``"aborted"``) and ``reset``.

This module moves bytes and reads the clock; what they mean and what to answer is
decided in :mod:`federation.bridge.core`, which takes ``now`` and bytes.
"""

from __future__ import annotations

import functools
import logging
import math
import socket
import threading
import time
from typing import IO, Any

import zenoh

from federation.bridge.core import BridgeCore
from federation.core import keys, wire
from federation.core.counters import Count
from federation.core.keys import AgentId
from federation.core.schedule import next_tick
from federation.runtime.agent import RateLimitedLog
from federation.runtime.clock import ExecClock
from federation.runtime.heap import freeze_startup_heap
from federation.runtime.names import (
    NAME_CHECKS_AFTER,
    NameTaken,
    clash_message,
    look_again,
    name_alive,
)
from federation.runtime.syncglue import Answer, Served, SyncQuerier, serve_query
from schemas.bridge import UdpBridgeConfig, format_address
from schemas.config import ConfigError
from schemas.messages import Status

__all__ = ["UdpBridge", "bind_udp", "run_bridge"]

log = logging.getLogger("fedlab.bridge")

_DATAGRAM_MAX = 2048  # larger than any valid packet: an oversize one reads as wrong-sized
_SMALL_MAX = 1024  # bytes: far more than a pose or a sync reply; larger ones are not read
_STATUS_MAX = 1 << 20  # bytes: a status or a command larger than this is not read


class UdpBridge:
    """The I/O around :class:`~federation.bridge.core.BridgeCore`: one UDP socket, one
    Zenoh session, and the clock that stamps what they carry.

    ``start()``, ``run(stop)``, ``close()``. Threads: a receiver reads the socket
    (timestamps on arrival, replies at once); Zenoh's network thread runs the
    callbacks (``indirect=False``); ``run`` sends requests, publishes status and
    declares or undeclares the liveliness token as the legacy agent comes and goes.
    All of them call into the core under one lock; sends happen outside it.
    """

    def __init__(
        self,
        config: UdpBridgeConfig,
        session: Any,
        sock: socket.socket | None = None,
        clock: ExecClock | None = None,
    ):
        self.config = config
        self.session = session
        self.clock = clock or ExecClock()
        self.rejects = RateLimitedLog(log)
        self.sock = sock if sock is not None else bind_udp(config.listen_address)
        self.peer_addr = _resolve(config.peer_address, self.sock.family)
        # The core compares sources with --peer as datagrams from it will give theirs.
        self.core = BridgeCore(config, (str(self.peer_addr[0]), int(self.peer_addr[1])))
        self.me = config.me
        self._lock = threading.Lock()  # one call into the core at a time
        self._declared: list[Any] = []
        self._token: Any = None
        self._pose_pub: Any = None
        self._status_pub: Any = None
        self._querier: SyncQuerier | None = None  # the reference's sync key
        self._followed_sub: Any = None
        self._unsynced_noted = False
        self._receiver: threading.Thread | None = None
        self._stop = threading.Event()
        self._status_file: IO[str] | None = None
        self._name_checks: list[float] = []  # host monotonic times of the next looks

    @property
    def listen_address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    def _count(self, name: Count) -> None:
        with self._lock:
            self.core.count(name)

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> None:
        """Declare everything; refuse (NameTaken) if the name is already in the federation."""
        s, cfg, callback = self.session, self.config, zenoh.handlers.Callback
        # Before the liveliness subscriber: once a session watches liveliness, its own
        # lookups may come back empty (federation/runtime/host.py).
        if name_alive(s, self.key(self.me)):
            raise NameTaken(
                f"agent {self.me} is already in federation {cfg.federation}: stop it first "
                "or bridge the legacy agent under another --as"
            )
        self._declared.append(
            s.declare_queryable(self.key(self.me, "sync"), callback(self._on_query, indirect=False))
        )
        self._pose_pub = s.declare_publisher(self.key(self.me, "pose"), express=True)
        self._status_pub = s.declare_publisher(self.key(self.me, "status"))
        self._declared += [self._pose_pub, self._status_pub]
        self._declared.append(
            s.liveliness().declare_subscriber(
                keys.all_agents(cfg.federation),
                callback(self._on_liveliness, indirect=False),
                history=True,
            )
        )
        self._declared.append(
            s.declare_subscriber(
                keys.control_key(cfg.federation), callback(self._on_control, indirect=False)
            )
        )
        if cfg.role == "follower" and cfg.follow is None:
            self._declared.append(
                s.declare_subscriber(
                    keys.all_of(cfg.federation, "status"), callback(self._on_status, indirect=False)
                )
            )
        followed = cfg.followed
        if followed is not None and cfg.role == "follower":
            self._use_reference(followed)
        elif followed is not None:  # a leader bridge: the followed pose only
            self._subscribe_pose(followed)
        if cfg.status_json is not None:
            cfg.status_json.parent.mkdir(parents=True, exist_ok=True)
            self._status_file = cfg.status_json.open("a", encoding="utf-8")
        log.info(
            "bridge %s (%s) up: UDP %s <-> legacy agent %s, federation %s",
            self.me, cfg.role, format_address(self.listen_address), cfg.peer_text,
            cfg.federation,
        )  # fmt: skip

    def close(self) -> None:
        """Undeclare the token first, then the rest; close the socket. The caller closes
        the session."""
        self._set_token(False, quiet=True)
        for entity in reversed(self._declared):
            _undeclare(entity)  # a session already closed by zenoh is fine
        self._declared.clear()
        if self._querier is not None:
            self._querier.close()
        self._stop.set()  # the receiver thread, if run() did not end normally
        if self._receiver is not None:
            self._receiver.join(2.0)
        self.sock.close()
        if self._status_file is not None:
            self._status_file.close()
            self._status_file = None

    def run(self, stop: threading.Event) -> None:
        """Until ``stop`` is set (or ``duration`` has passed): requests to the legacy agent
        and to the reference every ``sync_period``, status every ``status_period``."""
        cfg = self.config
        self._stop = stop
        # The first packet goes out before any is expected: a stateful firewall in front
        # of the bridge then lets the legacy agent's packets in. The requests that follow
        # every sync_period are the keepalive.
        log.info("opening the UDP flow to %s", cfg.peer_text)
        self._send_legacy_request()
        self._receiver = threading.Thread(
            target=self._receive_loop, args=(stop,), name="bridge-udp", daemon=True
        )
        self._receiver.start()
        t0 = time.monotonic()
        deadline = t0 + cfg.duration if cfg.duration is not None else math.inf
        self._maintain()
        self._send_reference_request()
        next_sync, next_status = t0 + cfg.sync_period, t0 + cfg.status_period
        while not stop.is_set():
            now = time.monotonic()
            if now >= deadline:
                break
            if now >= next_sync:
                self._send_legacy_request()
                self._maintain()
                self._send_reference_request()
                next_sync = next_tick(next_sync, cfg.sync_period, now)
            if now >= next_status:
                self.publish_status()
                next_status = next_tick(next_status, cfg.status_period, now)
            stop.wait(max(0.0, min(next_sync, next_status, deadline) - time.monotonic()))
        stop.set()  # the receiver too
        self.publish_status()

    # -- the bridge's loop -------------------------------------------------------------
    def _send_legacy_request(self) -> None:
        with self._lock:
            payload = self.core.legacy_request(self.clock.now())
        try:
            self.sock.sendto(payload, self.peer_addr)
        except OSError as error:  # unreachable, no route: keep trying at the next tick
            self._count(Count.UDP_SEND_ERRORS)
            self.rejects("udp send", f"to {self.config.peer_text}: {error}")

    def _send_reference_request(self) -> None:
        if self._querier is None:
            return
        with self._lock:
            payload = self.core.reference_request(self.clock.now())
            reference = self.core.reference_id
        if payload is None:
            return
        try:
            self._querier.request(payload)
        except Exception as error:  # session closing, or zenoh refusing the query
            log.warning("sync request to %s failed: %s", reference, error)

    def _maintain(self) -> None:
        """Liveliness token while the legacy agent answers (and the name is its own);
        reference found or rejoined."""
        with self._lock:
            found = self.core.maintain(self.clock.now())
        self._check_name_again(time.monotonic())
        self._set_token(found.legacy_alive)
        if found.rejoined is not None:
            log.info("reference %s rejoined: forgetting its old clock", found.rejoined)
        if found.leaders:
            names = ", ".join(map(str, found.leaders))
            log.warning("several leaders (%s): following %s", names, found.follow)
        if found.follow is not None:
            self._use_reference(found.follow)

    def _use_reference(self, agent: AgentId) -> None:
        """Query ``agent``'s sync key and take its pose (the core already syncs afresh)."""
        if self._querier is not None:
            self._querier.close()
        self._querier = SyncQuerier(
            self.session, self.key(agent, "sync"), self.config.sync_timeout, self.clock.read,
            self._on_reference_answer,
        )  # fmt: skip
        self._subscribe_pose(agent)
        log.info("reference time: %s's clock; legacy agent receives its pose", agent)

    def _subscribe_pose(self, agent: AgentId) -> None:
        self._drop(self._followed_sub)
        self._followed_sub = self.session.declare_subscriber(
            self.key(agent, "pose"), zenoh.handlers.Callback(self._on_pose, indirect=False)
        )
        self._declared.append(self._followed_sub)

    def _drop(self, entity: Any) -> None:
        if entity is not None:
            self._declared.remove(entity)
            _undeclare(entity)

    def _set_token(self, present: bool, quiet: bool = False) -> None:
        if present and self._token is None:
            with self._lock:
                # Another process took the name while the legacy agent was away (or before
                # it first answered): the bridge no longer speaks for it.
                taken = self.core.name_alive_elsewhere() and self.core.hold_for_name(
                    f"{self.me} is alive in federation {self.config.federation} in another process"
                )
            if taken:
                self._say_held()
            if self.core.name_clash is not None:
                return
            self._token = self.session.liveliness().declare_token(self.key(self.me))
            self._name_checks = [time.monotonic() + after for after in NAME_CHECKS_AFTER]
            log.info("legacy agent at %s answers: %s joined", self.config.peer_text, self.me)
        elif not present and self._token is not None:
            _undeclare(self._token)
            self._token = None
            if not quiet:
                log.warning(
                    "legacy agent at %s silent for %.1f s: %s left",
                    self.config.peer_text, self.config.legacy_timeout, self.me,
                )  # fmt: skip

    def _check_name_again(self, host: float) -> None:
        """At each of ``NAME_CHECKS_AFTER`` after the token is declared (host monotonic
        ``host``): ask who answers the legacy agent's sync key, as every agent does
        (:func:`~federation.runtime.names.look_for_others`); another session there
        means another process under the name, and the bridge stops speaking for it
        for good (:meth:`BridgeCore.hold_for_name`)."""

        def clash(sessions: list[str]) -> None:
            with self._lock:
                held = self.core.hold_for_name(
                    clash_message(str(self.me), self.config.federation, sessions)
                )
            if held:
                self._say_held()

        key = self.key(self.me, "sync")
        look_again(self._name_checks, host, self.session, key, self.clock.now, clash)

    def _say_held(self) -> None:
        log.error(
            "%s: the bridge no longer speaks for the legacy agent at %s (no replies to it, "
            "no pose from it); stop one of them and restart the other",
            self.core.name_clash, self.config.peer_text,
        )  # fmt: skip

    def status(self) -> Status:
        t, host = self.clock.read()
        with self._lock:
            return self.core.status(t, host)

    def publish_status(self) -> None:
        line = self.status().model_dump_json()
        try:
            self._status_pub.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as error:
            log.warning("status not published: %s", error)
        if self._status_file is not None:
            self._status_file.write(line + "\n")
            self._status_file.flush()

    # -- the UDP receiver thread -------------------------------------------------------
    def _receive_loop(self, stop: threading.Event) -> None:
        self.sock.settimeout(0.1)  # bounds how long a stop waits
        while not stop.is_set():
            try:
                data, addr = self.sock.recvfrom(_DATAGRAM_MAX)
            except TimeoutError:
                continue
            except OSError as error:  # e.g. an ICMP error reported on the socket
                if stop.is_set():
                    break
                self._count(Count.UDP_RECEIVE_ERRORS)
                self.rejects("udp receive", str(error))
                continue
            now = self.clock.now()  # read on arrival: t2 or t3
            try:
                self._on_datagram(data, addr, now)
            except Exception:
                log.exception("datagram from %s failed", addr)

    def _on_datagram(self, data: bytes, addr: Any, now: float) -> None:
        with self._lock:  # the core decides whose datagrams are heard, and how many answered
            outcome = self.core.on_datagram(data, (addr[0], addr[1]), now)
        if outcome.reply is not None:
            try:
                self.sock.sendto(outcome.reply, addr)
            except OSError as error:
                self._count(Count.UDP_SEND_ERRORS)
                self.rejects("udp send", f"to {format_address(addr[:2])}: {error}")
        if outcome.pose is not None:
            self._pose_pub.put(outcome.pose)
        if outcome.kind == "unsynced":
            if not self._unsynced_noted:  # normal until the reference answers: say it once
                log.info("legacy agent's requests wait for reference time (no reply yet)")
                self._unsynced_noted = True
        elif outcome.reply is not None:
            self._unsynced_noted = False  # said again should reference time be lost again
        elif outcome.rejected is not None:
            source = format_address(addr[:2])  # only said on a drop: not for every datagram
            self.rejects(f"udp datagram ({outcome.kind})", f"from {source}: {outcome.rejected}")

    # -- Zenoh callbacks: quick, and never raise ---------------------------------------
    def _on_query(self, query: Any) -> None:
        now = self.clock.now()  # read on arrival: the paper's t2
        serve_query(query, functools.partial(self._answer_query, now, query.key_expr))

    def _answer_query(self, now: float, key: object, payload: Any) -> Served | None:
        """The reply to a sync request for the legacy agent, received at ``now`` (None: no
        reply, as for a lost packet, while the legacy agent's clock is unknown)."""
        data = payload.to_bytes() if payload is not None else b""
        try:
            with self._lock:
                answer = self.core.on_sync_query(data, now)
        except wire.DecodeError as error:
            self.rejects("sync request", f"{key}: {error}")
            return None
        if answer is None:
            return None
        reply, offset = answer
        return reply, wire.encode_request(self.clock.now() + offset)  # send time, legacy clock

    def _on_reference_answer(self, answer: Answer) -> None:
        if not answer.ok:
            self._count(Count.SYNC_REPLY_ERRORS)
            return
        if answer.size > _SMALL_MAX:
            self._count(Count.SYNC_REPLY_OVERSIZED)
            return
        with self._lock:
            accepted = self.core.on_reference_reply(
                answer.payload(), answer.t3, replier=answer.source
            )
            reason = self.core.reference.client.last_rejection
            reference = self.core.reference_id
        if not accepted:
            self.rejects(f"sync reply ({reason})", f"from {reference}")

    def _on_pose(self, sample: Any) -> None:
        now = self.clock.now()
        try:
            if len(sample.payload) > _SMALL_MAX:
                self._count(Count.POSE_OVERSIZED)
                return
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            info = sample.source_info
            source = None if info is None else str(info.source_id.zid)
            payload = sample.payload.to_bytes()
            with self._lock:
                self.core.on_followed_pose(
                    payload, now, None if parsed is None else parsed[0], source
                )
        except wire.DecodeError as error:
            self.rejects("pose sample", f"{sample.key_expr}: {error}")
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_status(self, sample: Any) -> None:
        try:
            if len(sample.payload) > _STATUS_MAX:
                self._count(Count.STATUS_OVERSIZED)
                return
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            if parsed is None:
                return
            payload = sample.payload.to_bytes()
            with self._lock:
                self.core.on_status(payload, parsed[0])
        except Exception:
            self.rejects("status sample", f"{sample.key_expr}: failed")

    def _on_control(self, sample: Any) -> None:
        try:
            if len(sample.payload) > _STATUS_MAX:
                self._count(Count.CONTROL_OVERSIZED)
                return
            payload = sample.payload.to_bytes()
            with self._lock:
                done = self.core.on_control(payload)
            if done is not None:
                log.warning("%s: %s", self.me, done)
        except Exception:
            log.exception("control sample on %s failed", sample.key_expr)

    def _on_liveliness(self, sample: Any) -> None:
        try:
            alive = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                self.core.on_liveliness(str(sample.key_expr), alive)
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)


def run_bridge(
    config: UdpBridgeConfig, session: Any, sock: socket.socket, stop: threading.Event
) -> None:
    """Bridge on an open session and bound socket until ``stop`` (or ``duration``); the
    socket is closed on return, the session is the caller's."""
    try:
        bridge = UdpBridge(config, session, sock)
    except BaseException:  # e.g. --peer does not resolve
        sock.close()
        raise
    try:
        bridge.start()
        freeze_startup_heap()
        bridge.run(stop)
    finally:
        bridge.close()
    log.info("bridge %s stopped", config.agent)


def bind_udp(address: tuple[str, int]) -> socket.socket:
    """The bridge's one UDP socket, bound to ``address``; ConfigError if it cannot be."""
    text = format_address(address)
    try:
        infos = socket.getaddrinfo(*address, type=socket.SOCK_DGRAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as error:
        raise ConfigError(f"--listen {text}: {error}") from None
    family, kind, proto, _, sockaddr = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.bind(sockaddr)
    except OSError as error:
        sock.close()
        raise ConfigError(f"--listen {text}: cannot bind: {error}") from None
    return sock


def _resolve(address: tuple[str, int], family: int) -> Any:
    try:
        infos = socket.getaddrinfo(*address, family=family, type=socket.SOCK_DGRAM)
    except socket.gaierror as error:
        raise ConfigError(f"--peer {format_address(address)}: {error}") from None
    return infos[0][4]


def _undeclare(entity: Any) -> None:
    try:
        entity.undeclare()
    except Exception as error:  # a session already closed by zenoh
        log.debug("undeclare failed: %s", error)

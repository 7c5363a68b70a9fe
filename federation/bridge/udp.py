"""``fedlab bridge udp``: an unchanged legacy agent that speaks the paper's UDP packets
joins a federation as an agent like any other.

The legacy agent (a Simulink model, say) knows one peer: the bridge's UDP address. It
sends 8-byte requests there and answers the bridge's 8-byte requests with 64-byte
replies (NOTES.md, paper section 3.2). The bridge translates both directions::

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
paper's two channels).

A datagram of another size, holding NaN or infinity, or (for requests) from a host
other than ``--peer``'s, is dropped, logged (rate-limited) and counted in status.

Status (JSON, ``schemas.messages.Status`` plus the bridge's fields)
    ``t_exec`` is the legacy agent's clock as the bridge estimates it (``clock``:
    ``"legacy"``), or the bridge's own clock before the first exchange (``clock``:
    ``"bridge"``); ``peers`` holds the reference agent, its offset relative to that
    clock as for every agent; ``legacy`` holds the UDP link (offset: legacy agent's
    clock minus the bridge's, delay, samples, ...); ``mode`` is ``"unmanaged"``: a
    legacy agent runs its own timeline and does not take execution control.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Literal, NamedTuple

import zenoh

from federation.core import keys, wire
from federation.core.estimators import DEFAULT_ESTIMATOR, ESTIMATORS, make_estimator
from federation.core.keys import AgentId
from federation.core.sync import DEFAULT_WINDOW, SyncClient
from federation.runtime.agent import RateLimitedLog, peer_status
from federation.runtime.clock import ExecClock
from schemas.config import ConfigError
from schemas.messages import PeerStatus, Status

__all__ = [
    "BridgeConfig",
    "BridgeCore",
    "Outcome",
    "UdpBridge",
    "bind_udp",
    "parse_address",
    "register",
]

log = logging.getLogger("fedlab.bridge")

Role = Literal["leader", "follower"]
_DATAGRAM_MAX = 2048  # larger than any valid packet: an oversize one reads as wrong-sized


def parse_address(text: str, what: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` for IPv6) as (host, port); ConfigError if malformed."""
    host, sep, port_text = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise ConfigError(f"{what} {text!r}: expected HOST:PORT, e.g. 127.0.0.1:9000")
    return host, port


@dataclass(frozen=True)
class BridgeConfig:
    """What ``fedlab bridge udp`` was asked to do (times in seconds)."""

    agent: AgentId
    listen: tuple[str, int]
    peer: tuple[str, int]
    federation: str = keys.DEFAULT_FEDERATION
    role: Role = "follower"
    follow: AgentId | None = None
    sync_period: float = 0.1
    sync_timeout: float = 0.5
    sync_window: float = DEFAULT_WINDOW
    estimator: str = DEFAULT_ESTIMATOR
    legacy_timeout: float = 2.0
    status_period: float = 1.0
    status_json: Path | None = None
    duration: float | None = None

    def __post_init__(self) -> None:
        keys.validate_name(self.federation, "federation name")
        for name in ("sync_period", "sync_timeout", "sync_window", "legacy_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"--{name.replace('_', '-')} must be positive seconds")
        if not (math.isfinite(self.status_period) and self.status_period > 0):
            raise ConfigError("--status-period must be positive seconds")
        if self.follow == self.agent:
            raise ConfigError(f"{self.agent} cannot follow itself")
        if self.estimator not in ESTIMATORS:
            raise ConfigError(f"unknown estimator {self.estimator!r}")

    @property
    def peer_text(self) -> str:
        host, port = self.peer
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class Outcome(NamedTuple):
    """What a datagram from the legacy side led to."""

    reply: bytes | None = None  # send back to the datagram's source
    pose: bytes | None = None  # publish as the legacy agent's pose sample
    rejected: str | None = None  # why it was dropped, for the log
    kind: str | None = None  # what was dropped: "malformed", "unsynced" or "sync reply"


@dataclass
class _Link:
    client: SyncClient
    alive: bool = False
    last_seen: float = -math.inf  # bridge clock of the last accepted exchange


class BridgeCore:
    """The bridge's protocol logic, free of I/O: bytes and the bridge's clock go in,
    bytes to send come out. Thread-safe (the UDP thread, Zenoh's callbacks and the
    bridge's loop all call in); every method is quick.

    Clocks: ``now`` is always the bridge's own clock. ``legacy`` estimates the legacy
    agent's clock minus the bridge's, ``reference`` the reference agent's minus the
    bridge's (the reference of a leader bridge is the legacy agent itself).
    """

    def __init__(self, config: BridgeConfig):
        self.config = config
        self.legacy = _Link(self._client())
        self.reference_id: AgentId | None = (
            config.agent if config.role == "leader" else config.follow
        )
        self.reference = _Link(self._client())
        self.legacy_pose: wire.PoseSample | None = None  # stamped on the legacy agent's clock
        self.followed_pose: wire.PoseSample | None = None  # stamped on the followed agent's
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()

    def _client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), cfg.sync_timeout)

    def count(self, name: str) -> None:
        with self._lock:
            self.counters[name] += 1

    # -- clocks ----------------------------------------------------------------------
    def legacy_offset(self, now: float) -> float | None:
        """Legacy agent's clock minus the bridge's; None until it answers (or once lost)."""
        with self._lock:
            return self._legacy_offset(now)

    def _legacy_offset(self, now: float) -> float | None:
        return self.legacy.client.offset_at(now) if self.legacy.alive else None

    def reference_offset(self, now: float) -> float | None:
        """Reference agent's clock minus the bridge's (Eq. 5's offset, via the bridge)."""
        with self._lock:
            return self._reference_offset(now)

    def _reference_offset(self, now: float) -> float | None:
        if self.config.role == "leader":
            return self._legacy_offset(now)
        if self.reference_id is None:
            return None
        return self.reference.client.offset_at(now)

    # -- the legacy side (UDP) ---------------------------------------------------------
    def legacy_request(self, now: float) -> bytes:
        """The bridge's own 8-byte request to the legacy agent, sent at ``now``."""
        with self._lock:
            self.counters["udp_requests_sent"] += 1
            return self.legacy.client.request(now)

    def on_datagram(self, data: bytes, now: float) -> Outcome:
        """A datagram from the legacy agent, read at ``now``: its request (8 bytes) or its
        reply to ours (64 bytes)."""
        if len(data) == wire.REQUEST_SIZE:
            return self._on_legacy_request(data, now)
        if len(data) == wire.REPLY_SIZE:
            return self._on_legacy_reply(data, now)
        self.count("udp_malformed")
        sizes = f"{wire.REQUEST_SIZE} or {wire.REPLY_SIZE}"
        return Outcome(rejected=f"expected {sizes} bytes, got {len(data)}", kind="malformed")

    def _on_legacy_request(self, data: bytes, now: float) -> Outcome:
        try:
            t1 = wire.decode_request(data)
        except wire.DecodeError as error:
            self.count("udp_malformed")
            return Outcome(rejected=str(error), kind="malformed")
        with self._lock:
            offset = self._reference_offset(now)
            if offset is None:
                self.counters["udp_requests_unsynced"] += 1
                return Outcome(rejected="no reference time yet", kind="unsynced")
            pose = self.followed_pose.pose if self.followed_pose else wire.Pose()
            self.counters["udp_requests_served"] += 1
        # t2 on the reference clock: the legacy agent's Eq. 4 then gives leader minus itself.
        return Outcome(reply=wire.encode_reply(t1, now + offset, pose))

    def _on_legacy_reply(self, data: bytes, now: float) -> Outcome:
        with self._lock:
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
        with self._lock:
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
        legacy agent's behalf and its send time (legacy clock), or None (no reply)."""
        try:
            t1 = wire.decode_request(payload)
        except wire.DecodeError:
            self.count("sync_requests_malformed")
            raise
        with self._lock:
            offset = self._legacy_offset(now)
            if offset is None:
                self.counters["sync_requests_unsynced"] += 1
                return None
            pose = self.legacy_pose.pose if self.legacy_pose else wire.Pose()
            self.counters["sync_requests_served"] += 1
        return wire.encode_reply(t1, now + offset, pose), offset

    def reference_request(self, now: float) -> bytes | None:
        """The next sync request to the reference agent (None for a leader bridge)."""
        with self._lock:
            if self.config.role == "leader" or self.reference_id is None:
                return None
            return self.reference.client.request(now)

    def on_reference_reply(self, payload: bytes, now: float, t2s: float | None = None) -> bool:
        with self._lock:
            link = self.reference
            if link.client.receive(payload, now, t2s) is None:
                return False
            link.last_seen = now
            link.client.offset_at(now)  # fit now, off the legacy agent's request path
            return True

    def reference_presence(self, agent: AgentId, alive: bool) -> None:
        """The reference's liveliness token came (PUT) or went (DELETE)."""
        with self._lock:
            if agent == self.reference_id:
                self.reference.alive = alive

    def on_followed_pose(self, payload: bytes) -> None:
        try:
            sample = wire.decode_pose(payload)
        except wire.DecodeError:
            self.count("pose_malformed")
            raise
        with self._lock:
            self.followed_pose = sample
            self.counters["pose_received"] += 1

    def set_reference(self, agent: AgentId, alive: bool) -> None:
        """Sync with ``agent`` afresh from now on (found by its status, or rejoined with a
        new clock); ``alive``: its liveliness token is present."""
        with self._lock:
            self.reference_id = agent
            self.reference = _Link(self._client(), alive)
            self.followed_pose = None

    # -- status ------------------------------------------------------------------------
    def status(self, now: float, host: float) -> Status:
        cfg = self.config
        with self._lock:
            legacy = self._legacy_offset(now)
            base = 0.0 if legacy is None else legacy  # status is on the legacy agent's clock
            ref = self._reference_offset(now)
            peers = {}
            if cfg.role == "follower" and self.reference_id is not None:
                peers[str(self.reference_id)] = _peer_status(self.reference, now, base)
            link = _peer_status(self.legacy, now, 0.0).model_dump()
            pose = list(self.legacy_pose.pose) if self.legacy_pose else list(wire.Pose())
            counters = dict(self.counters)
            followed = self.followed_pose
        t_exec = now + base
        follow = cfg.follow if cfg.role == "leader" else self.reference_id
        pose_age = None
        if followed is not None and cfg.role == "follower" and ref is not None:
            pose_age = now + ref - followed.t  # its samples are stamped on its clock
        return Status(
            agent=str(cfg.agent),
            federation=cfg.federation,
            role=cfg.role,
            reference=str(self.reference_id or cfg.agent),
            t_exec=t_exec,
            host_monotonic=host,
            t_sim=None if ref is None else now + ref,
            mode="unmanaged",
            platform=f"udp:{cfg.peer_text}",
            follow=None if follow is None else str(follow),
            pose_age=pose_age,
            pose=pose,
            peers=peers,
            counters=counters,
            clock="bridge" if legacy is None else "legacy",
            legacy={"address": cfg.peer_text, "bridge_t_exec": now, **link},
        )


def _peer_status(link: _Link, now: float, base: float) -> PeerStatus:
    """A link's view as in every agent's status; ``base``: the status clock minus the
    bridge's, so the offset is relative to the clock ``t_exec`` is on."""
    return peer_status(link.client, now, link.alive, base)


class UdpBridge:
    """The I/O around :class:`BridgeCore`: one UDP socket, one Zenoh session.

    ``start()``, ``run(stop)``, ``close()``. Threads: a receiver reads the socket
    (timestamps on arrival, replies at once); Zenoh's network thread runs the
    callbacks (``indirect=False``); ``run`` sends requests, publishes status and
    declares or undeclares the liveliness token as the legacy agent comes and goes.
    """

    def __init__(
        self,
        config: BridgeConfig,
        session: Any,
        sock: socket.socket | None = None,
        clock: ExecClock | None = None,
    ):
        self.config = config
        self.session = session
        self.clock = clock or ExecClock()
        self.core = BridgeCore(config)
        self.rejects = RateLimitedLog(log)
        self.sock = sock if sock is not None else bind_udp(config.listen)
        self.peer_addr = _resolve(config.peer, self.sock.family)
        self.me = config.agent
        self._declared: list[Any] = []
        self._token: Any = None
        self._pose_pub: Any = None
        self._status_pub: Any = None
        self._querier: Any = None
        self._on_reply: Any = None
        self._followed_sub: Any = None
        self._leaders: set[AgentId] = set()  # agents whose status says role "leader"
        self._alive: set[AgentId] = set()  # agents whose liveliness token is present
        self._seen_gone: set[AgentId] = set()  # agents whose token went away
        self._rejoined = False  # the reference's token came back: a new clock
        self._state_lock = threading.Lock()
        self._leader_warned = False
        self._unsynced_noted = False
        self._receiver: threading.Thread | None = None
        self._stop = threading.Event()
        self._status_file: IO[str] | None = None

    @property
    def listen_address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return str(host), int(port)

    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> None:
        s, cfg, callback = self.session, self.config, zenoh.handlers.Callback
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
        if cfg.role == "follower" and cfg.follow is None:
            self._declared.append(
                s.declare_subscriber(
                    keys.all_of(cfg.federation, "status"), callback(self._on_status, indirect=False)
                )
            )
        if self.core.reference_id is not None and cfg.role == "follower":
            self._use_reference(self.core.reference_id)
        elif cfg.follow is not None:  # a leader bridge: the followed pose only
            self._subscribe_pose(cfg.follow)
        if cfg.status_json is not None:
            cfg.status_json.parent.mkdir(parents=True, exist_ok=True)
            self._status_file = cfg.status_json.open("a", encoding="utf-8")
        log.info(
            "bridge %s (%s) up: UDP %s:%d <-> legacy agent %s, federation %s",
            self.me, cfg.role, *self.listen_address, cfg.peer_text, cfg.federation,
        )  # fmt: skip

    def close(self) -> None:
        """Undeclare the token first, then the rest; close the socket. The caller closes
        the session."""
        self._set_token(False, quiet=True)
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception as error:  # a session already closed by zenoh
                log.debug("undeclare failed: %s", error)
        self._declared.clear()
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
        deadline = t0 + cfg.duration if cfg.duration else math.inf
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
                next_sync = _next_tick(next_sync, cfg.sync_period, now)
            if now >= next_status:
                self.publish_status()
                next_status = _next_tick(next_status, cfg.status_period, now)
            stop.wait(max(0.0, min(next_sync, next_status, deadline) - time.monotonic()))
        stop.set()  # the receiver too
        self.publish_status()

    # -- the bridge's loop -------------------------------------------------------------
    def _send_legacy_request(self) -> None:
        payload = self.core.legacy_request(self.clock.now())
        try:
            self.sock.sendto(payload, self.peer_addr)
        except OSError as error:  # unreachable, no route: keep trying at the next tick
            self.core.count("udp_send_errors")
            self.rejects("udp send", f"to {self.config.peer_text}: {error}")

    def _send_reference_request(self) -> None:
        if self._querier is None:
            return
        payload = self.core.reference_request(self.clock.now())
        if payload is None:
            return
        try:
            self._querier.get(self._on_reply, payload=payload)
        except Exception as error:  # session closing, or zenoh refusing the query
            log.warning("sync request to %s failed: %s", self.core.reference_id, error)

    def _maintain(self) -> None:
        """Liveliness token while the legacy agent answers; reference found or rejoined."""
        self._set_token(self.core.check_legacy(self.clock.now()))
        cfg = self.config
        if cfg.role != "follower":
            return
        with self._state_lock:
            rejoined, self._rejoined = self._rejoined, False
            leaders = sorted(self._leaders - {self.me})
            current = self.core.reference_id
            current_alive = current is not None and current in self._alive
        if rejoined and current is not None:
            log.info("reference %s rejoined: forgetting its old clock", current)
            with self._state_lock:
                self.core.set_reference(current, current in self._alive)
        if cfg.follow is not None or current_alive or not leaders:
            return
        if current is not None and current in leaders:
            return  # its status still arrives: its token is on its way
        if len(leaders) > 1 and not self._leader_warned:
            names = ", ".join(map(str, leaders))
            log.warning("several leaders (%s): following %s", names, leaders[0])
            self._leader_warned = True
        self._use_reference(leaders[0])

    def _use_reference(self, agent: AgentId) -> None:
        self._drop(self._querier)
        self._querier = self.session.declare_querier(
            self.key(agent, "sync"),
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.config.sync_timeout,
            express=True,
        )
        self._declared.append(self._querier)
        self._on_reply = zenoh.handlers.Callback(self._on_reference_reply, indirect=False)
        with self._state_lock:
            self.core.set_reference(agent, agent in self._alive)
        self._subscribe_pose(agent)
        log.info("reference time: %s's clock; legacy agent receives its pose", agent)

    def _subscribe_pose(self, agent: AgentId) -> None:
        self._drop(self._followed_sub)
        self._followed_sub = self.session.declare_subscriber(
            self.key(agent, "pose"), zenoh.handlers.Callback(self._on_pose, indirect=False)
        )
        self._declared.append(self._followed_sub)

    def _drop(self, entity: Any) -> None:
        if entity is None:
            return
        self._declared.remove(entity)
        try:
            entity.undeclare()
        except Exception as error:
            log.debug("undeclare failed: %s", error)

    def _set_token(self, present: bool, quiet: bool = False) -> None:
        if present and self._token is None:
            self._token = self.session.liveliness().declare_token(self.key(self.me))
            log.info("legacy agent at %s answers: %s joined", self.config.peer_text, self.me)
        elif not present and self._token is not None:
            try:
                self._token.undeclare()
            except Exception as error:
                log.debug("undeclare failed: %s", error)
            self._token = None
            if not quiet:
                log.warning(
                    "legacy agent at %s silent for %.1f s: %s left",
                    self.config.peer_text, self.config.legacy_timeout, self.me,
                )  # fmt: skip

    def status(self) -> Status:
        t, host = self.clock.read()
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
                self.core.count("udp_receive_errors")
                self.rejects("udp receive", str(error))
                continue
            now = self.clock.now()  # read on arrival: t2 or t3
            try:
                self._on_datagram(data, addr, now)
            except Exception:
                log.exception("datagram from %s failed", addr)

    def _on_datagram(self, data: bytes, addr: Any, now: float) -> None:
        if addr[0] != self.peer_addr[0]:
            self.core.count("udp_foreign")
            self.rejects("udp datagram", f"from {addr[0]}:{addr[1]}: not the legacy agent's host")
            return
        outcome = self.core.on_datagram(data, now)
        if outcome.reply is not None:
            try:
                self.sock.sendto(outcome.reply, addr)
            except OSError as error:
                self.core.count("udp_send_errors")
                self.rejects("udp send", f"to {addr[0]}:{addr[1]}: {error}")
        if outcome.pose is not None:
            self._pose_pub.put(outcome.pose)
        if outcome.kind == "unsynced":
            if not self._unsynced_noted:  # normal until the reference answers: say it once
                log.info("legacy agent's requests wait for reference time (no reply yet)")
                self._unsynced_noted = True
        elif outcome.rejected is not None:
            self.rejects(
                f"udp datagram ({outcome.kind})", f"from {addr[0]}:{addr[1]}: {outcome.rejected}"
            )

    # -- Zenoh callbacks: quick, and never raise ---------------------------------------
    def _on_query(self, query: Any) -> None:
        now = self.clock.now()  # read on arrival: the paper's t2
        try:
            payload = query.payload
            try:
                answer = self.core.on_sync_query(
                    payload.to_bytes() if payload is not None else b"", now
                )
            except wire.DecodeError as error:
                self.rejects("sync request", f"{query.key_expr}: {error}")
                return
            if answer is None:
                return  # the legacy agent's clock is unknown: no reply, as for a lost packet
            reply, offset = answer
            t2s = wire.encode_request(self.clock.now() + offset)  # send time, legacy clock
            query.reply(query.key_expr, reply, attachment=t2s)
        except Exception:
            log.exception("sync query on %s failed", query.key_expr)
        finally:
            query.drop()  # release now, or the querier waits for its timeout

    def _on_reference_reply(self, reply: Any) -> None:
        now = self.clock.now()  # read on arrival: the paper's t3
        try:
            if reply.ok is None:
                self.core.count("sync_reply_errors")
                return
            if not self.core.on_reference_reply(reply.ok.payload.to_bytes(), now):
                reason = self.core.reference.client.last_rejection
                self.rejects(f"sync reply ({reason})", f"from {self.core.reference_id}")
        except Exception:
            log.exception("sync reply from %s failed", self.core.reference_id)

    def _on_pose(self, sample: Any) -> None:
        try:
            self.core.on_followed_pose(sample.payload.to_bytes())
        except wire.DecodeError as error:
            self.rejects("pose sample", f"{sample.key_expr}: {error}")
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_status(self, sample: Any) -> None:
        try:
            status = json.loads(sample.payload.to_bytes())
            if status.get("role") == "leader":
                agent = AgentId.parse(str(status["agent"]))
                with self._state_lock:
                    self._leaders.add(agent)
        except (ValueError, KeyError, TypeError, AttributeError):
            pass  # a malformed status is the monitor's business

    def _on_liveliness(self, sample: Any) -> None:
        try:
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            if parsed is None or parsed[1] is not None:
                return
            agent, alive = parsed[0], sample.kind == zenoh.SampleKind.PUT
            with self._state_lock:
                self.core.reference_presence(agent, alive)
                if alive:
                    if agent == self.core.reference_id and agent not in self._alive:
                        self._rejoined = agent in self._seen_gone
                    self._alive.add(agent)
                else:
                    self._alive.discard(agent)
                    self._leaders.discard(agent)
                    self._seen_gone.add(agent)
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)


def bind_udp(address: tuple[str, int]) -> socket.socket:
    """The bridge's one UDP socket, bound to ``--listen``; ConfigError if it cannot be."""
    host, port = address
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as error:
        raise ConfigError(f"--listen {host}:{port}: {error}") from None
    family, kind, proto, _, sockaddr = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.bind(sockaddr)
    except OSError as error:
        sock.close()
        raise ConfigError(f"--listen {host}:{port}: cannot bind: {error}") from None
    return sock


def _resolve(address: tuple[str, int], family: int) -> Any:
    host, port = address
    try:
        infos = socket.getaddrinfo(host, port, family=family, type=socket.SOCK_DGRAM)
    except socket.gaierror as error:
        raise ConfigError(f"--peer {host}:{port}: {error}") from None
    return infos[0][4]


def _next_tick(previous: float, period: float, now: float) -> float:
    """Next deadline on the period's grid; skip missed ticks instead of bursting."""
    tick = previous + period
    return tick if tick > now else now + period


# -- command line ----------------------------------------------------------------------
def bridge_config(args: argparse.Namespace) -> BridgeConfig:
    try:
        agent = AgentId.parse(args.as_agent)
        follow = AgentId.parse(args.follow) if args.follow else None
    except ValueError as error:
        raise ConfigError(str(error)) from None
    try:
        return BridgeConfig(
            agent=agent,
            listen=parse_address(args.udp_listen, "--listen"),
            peer=parse_address(args.peer, "--peer"),
            federation=args.federation,
            role=args.role,
            follow=follow,
            sync_period=args.sync_period,
            sync_timeout=args.sync_timeout,
            sync_window=args.sync_window,
            estimator=args.estimator,
            legacy_timeout=args.legacy_timeout,
            status_period=args.status_period,
            status_json=args.status_json,
            duration=args.duration,
        )
    except ValueError as error:  # ConfigError is one
        raise ConfigError(str(error)) from None


def cmd_bridge_udp(args: argparse.Namespace) -> int:
    from federation.cli.common import open_interruptible, stop_on_signals, zenoh_options
    from federation.runtime.session import build_config

    config = bridge_config(args)
    conf = build_config(zenoh_options(args), default_mode="client")
    sock = bind_udp(config.listen)  # a port in use fails now, not after the router answers
    stop = stop_on_signals()
    try:
        session = open_interruptible(zenoh.open, conf, stop)
    except BaseException:
        sock.close()
        raise
    if session is None:
        sock.close()
        return 0
    from federation.runtime.heap import freeze_startup_heap

    with session:
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
    return 0


def register(
    sub: Any,
    formatter: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    """Add ``bridge udp``."""
    bridge = sub.add_parser(
        "bridge",
        help="join a legacy agent to the federation (the paper's UDP packets)",
        formatter_class=formatter,
        description="Bridges that let an unchanged legacy agent join the federation.",
        epilog=_EXAMPLE,
    )
    kinds = bridge.add_subparsers(dest="bridge", required=True, metavar="KIND")
    p = kinds.add_parser(
        "udp",
        help="a legacy agent speaking the paper's UDP packets (8-byte request, 64-byte reply)",
        formatter_class=formatter,
        description=(
            "Join an unchanged legacy agent that speaks the paper's UDP packets to the\n"
            "federation as LAB/NAME. Its 8-byte requests to --listen get 64-byte replies\n"
            "with t2 on the reference (leader's) clock and the followed agent's pose. The\n"
            "bridge's own requests to --peer (every --sync-period) give the legacy agent's\n"
            "clock and pose, served to the federation as LAB/NAME's sync, pose and status.\n"
            "The first request opens the firewall flow; the requests keep it open.\n\n"
            "Zenoh's own listen endpoint is -l here; --listen is the UDP address."
        ),
        epilog=_EXAMPLE,
        conflict_handler="resolve",  # --listen is the UDP address; Zenoh keeps -l
    )
    add_zenoh_flags(p)
    p.add_argument(
        "--as", dest="as_agent", required=True, metavar="LAB/NAME",
        help="the legacy agent's name in the federation",
    )  # fmt: skip
    p.add_argument(
        "--listen", dest="udp_listen", required=True, metavar="HOST:PORT",
        help="UDP address the legacy agent sends its requests to (and that sends ours)",
    )  # fmt: skip
    p.add_argument(
        "--peer", required=True, metavar="HOST:PORT",
        help="the legacy agent's UDP address: where the bridge's requests go",
    )  # fmt: skip
    p.add_argument(
        "--follow", metavar="LAB/NAME",
        help="agent whose clock and pose the legacy agent receives; "
        "none: the federation's leader, found by its status",
    )  # fmt: skip
    p.add_argument(
        "--role", choices=["follower", "leader"], default="follower",
        help="leader: the legacy agent's clock is the reference time",
    )  # fmt: skip
    p.add_argument("--federation", default=keys.DEFAULT_FEDERATION, help="federation name")
    p.add_argument(
        "--sync-period", type=float, default=0.1, metavar="S", help="seconds between requests"
    )
    p.add_argument("--sync-timeout", type=float, default=0.5, metavar="S", help="reply timeout")
    p.add_argument(
        "--sync-window", type=float, default=DEFAULT_WINDOW, metavar="S",
        help="offset averaging window",
    )  # fmt: skip
    p.add_argument(
        "--estimator", choices=list(ESTIMATORS), default=DEFAULT_ESTIMATOR,
        help="offset estimator for both links",
    )  # fmt: skip
    p.add_argument(
        "--legacy-timeout", type=float, default=2.0, metavar="S",
        help="seconds without a reply before the legacy agent counts as gone",
    )  # fmt: skip
    p.add_argument(
        "--status-period", type=float, default=1.0, metavar="S", help="seconds between status"
    )
    p.add_argument("--status-json", type=Path, metavar="FILE", help="append status lines here")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    p.set_defaults(func=cmd_bridge_udp)


_EXAMPLE = (
    "Example:\n"
    "  fedlab bridge udp --as rome/pinocchio --listen 0.0.0.0:9000 --peer 192.0.2.7:9001 \\\n"
    "      --follow kiruna/knatte -e tcp/127.0.0.1:7448"
)

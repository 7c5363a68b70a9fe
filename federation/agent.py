"""Agent runtime: the thin Zenoh layer around the sync client, the guidance and a platform.

Threads and who owns what:

- Zenoh's network thread runs the callbacks (``indirect=False``): the sync
  queryable reads ``t2`` and replies at once; a sync reply reads ``t3`` and is
  matched under ``_lock``; pose and liveliness samples are decoded and stored.
  Callbacks never raise and never block: a bad payload is logged and counted.
- The agent's own loop (``run``) steps the platform, publishes pose and status
  and sends sync requests (``session.get`` with a callback returns at once).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import zenoh

from agents.guidance import ReferenceManeuver, track_heading
from agents.kinematic import KinematicPlatform, Platform
from federation import keys, wire
from federation.clock import ExecClock
from federation.estimators import make_estimator
from federation.keys import AgentId
from federation.sync import SyncClient
from schemas.config import AgentConfig
from schemas.messages import PeerStatus, Status

__all__ = ["Agent", "AgentRuntime"]

log = logging.getLogger("fedlab.agent")


class RateLimitedLog:
    """Logs the first ``burst`` events of a kind, then every ``every``-th, with its count."""

    def __init__(self, logger: logging.Logger, burst: int = 5, every: int = 100):
        self.logger, self.burst, self.every = logger, burst, every
        self.counts: Counter[str] = Counter()
        self._lock = threading.Lock()

    def __call__(self, kind: str, message: str) -> None:
        with self._lock:
            self.counts[kind] += 1
            n = self.counts[kind]
        if n <= self.burst or n % self.every == 0:
            self.logger.warning("rejected %s (#%d): %s", kind, n, message)


@dataclass
class Peer:
    agent: AgentId
    client: SyncClient
    key: str
    alive: bool = True


class AgentRuntime:
    """One agent on an open Zenoh session. ``start()``, ``run(stop)``, ``close()``."""

    def __init__(
        self,
        config: AgentConfig,
        session: zenoh.Session,
        clock: ExecClock | None = None,
        platform: Platform | None = None,
        maneuver: Callable[[float], tuple[float, float]] | None = None,
    ):
        self.config = config
        self.session = session
        self.me = config.agent
        self.clock = clock or ExecClock(config.clock_offset, config.clock_drift_ppm)
        self.platform: Platform = platform or KinematicPlatform()
        self.maneuver = maneuver or ReferenceManeuver(start=config.sync_window)
        self.follow = AgentId.parse(config.follow) if config.follow else None
        self.reference = self.follow if config.role == "follower" and self.follow else self.me
        self.explicit_sync = {AgentId.parse(a) for a in config.sync_with}
        if self.explicit_sync and self.follow:
            self.explicit_sync.add(self.follow)
        self.pose = wire.Pose()
        self.peers: dict[AgentId, Peer] = {}
        self.latest_poses: dict[AgentId, wire.PoseSample] = {}
        self.counters: Counter[str] = Counter()
        self._count_lock = threading.Lock()
        self.rejects = RateLimitedLog(log)
        self._lock = threading.Lock()
        self._declared: list[Any] = []
        self._status_file: IO[str] | None = None
        self._record_file: IO[str] | None = None
        self._pose_file: IO[str] | None = None
        # Recorded lines not yet written: callbacks append, the agent's loop writes.
        self._records: list[str] = []
        self._pose_records: list[str] = []
        self._pose_pub: Any = None
        self._status_pub: Any = None

    def count(self, name: str) -> None:
        """Bump a counter; callbacks may run on several Zenoh threads at once."""
        with self._count_lock:
            self.counters[name] += 1

    # -- keys --------------------------------------------------------------
    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    # -- lifecycle ---------------------------------------------------------
    def start(self) -> None:
        s = self.session
        callback = zenoh.handlers.Callback
        self._declared.append(
            s.declare_queryable(
                self.key(self.me, "sync"), callback(self._on_sync_query, indirect=False)
            )
        )
        self._pose_pub = s.declare_publisher(self.key(self.me, "pose"), express=True)
        self._status_pub = s.declare_publisher(self.key(self.me, "status"))
        self._declared += [self._pose_pub, self._status_pub]
        if self.follow is not None:
            self._declared.append(
                s.declare_subscriber(
                    self.key(self.follow, "pose"), callback(self._on_pose, indirect=False)
                )
            )
        self._declared.append(
            s.liveliness().declare_subscriber(
                keys.all_agents(self.config.federation),
                callback(self._on_liveliness, indirect=False),
                history=True,
            )
        )
        self._declared.append(s.liveliness().declare_token(self.key(self.me)))
        self._status_file = _open_append(self.config.status_json)
        self._record_file = _open_append(self.config.record_sync)
        self._pose_file = _open_append(self.config.record_pose)
        log.info(
            "agent %s (%s) up in federation %s", self.me, self.config.role, self.config.federation
        )

    def close(self) -> None:
        """Undeclare everything (tokens and subscribers first); the caller closes the session."""
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception as error:  # a session already closed by zenoh
                log.debug("undeclare failed: %s", error)
        self._declared.clear()
        self._flush_records()
        for f in (self._status_file, self._record_file, self._pose_file):
            if f is not None:
                f.close()
        self._status_file = self._record_file = self._pose_file = None

    def run(self, stop: threading.Event) -> None:
        """The agent's loop, until ``stop`` is set or the configured duration has passed."""
        cfg = self.config
        t0 = time.monotonic()
        deadline = t0 + cfg.duration if cfg.duration else float("inf")
        pose_period = 1.0 / cfg.pose_rate
        next_pose = next_sync = t0
        next_status = t0 + cfg.status_period
        while not stop.is_set():
            now = time.monotonic()
            if now >= deadline:
                break
            if now >= next_pose:
                self.step()
                next_pose = _next_tick(next_pose, pose_period, now)
            if now >= next_sync:
                self.send_sync_requests()
                next_sync = _next_tick(next_sync, cfg.sync_period, now)
            if now >= next_status:
                self.publish_status()
                next_status = _next_tick(next_status, cfg.status_period, now)
            stop.wait(max(0.0, min(next_pose, next_sync, next_status, deadline) - time.monotonic()))
        self.publish_status()

    # -- the agent's own loop ----------------------------------------------
    def sim_time(self, t_exec: float) -> float | None:
        """Simulation time (Eq. 5): the reference agent's clock."""
        if self.reference == self.me:
            return t_exec
        peer = self.peers.get(self.reference)
        offset = peer.client.offset_at(t_exec) if peer else None
        return None if offset is None else t_exec + offset

    def step(self) -> None:
        """Advance guidance and platform, publish the pose."""
        t_exec = self.clock.now()
        if self.config.role == "leader":
            heading, rate = self.maneuver(t_exec)
        else:
            received = self.latest_poses.get(self.follow) if self.follow else None
            heading, rate = track_heading(received)
        self.pose = self.platform.step(t_exec, heading, rate)
        self._pose_pub.put(wire.encode_pose(t_exec, self.pose))
        if self._pose_file is not None:
            with self._lock:
                self._pose_records.append(f'{{"sent": true, "t": {t_exec!r}}}\n')

    def sync_targets(self) -> list[AgentId]:
        if self.explicit_sync:
            return [a for a in self.explicit_sync if a in self.peers and self.peers[a].alive]
        return [a for a, p in self.peers.items() if p.alive]

    def send_sync_requests(self) -> None:
        for agent in self.sync_targets():
            peer = self.peers[agent]
            with self._lock:
                payload = peer.client.request(self.clock.now())
            on_reply = functools.partial(self._on_sync_reply, peer)
            try:
                self.session.get(
                    peer.key,
                    zenoh.handlers.Callback(on_reply, indirect=False),
                    payload=payload,
                    timeout=self.config.sync_timeout,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    express=True,
                )
            except Exception as error:  # session closing, or zenoh refusing the query
                log.warning("sync request to %s failed: %s", agent, error)

    def status(self) -> Status:
        t_exec, host = self.clock.read()
        peers = {}
        with self._lock:
            for agent, peer in self.peers.items():
                c = peer.client
                last = c.last
                drift = getattr(c.estimator, "drift", None)
                peers[str(agent)] = PeerStatus(
                    offset=c.offset_at(t_exec),
                    bound=c.estimator.bound,
                    drift_ppm=None if drift is None else drift * 1e6,
                    delay=c.delay,
                    error_bound=last.error_bound if last else None,
                    last_offset=last.offset if last else None,
                    last_delay=last.delay if last else None,
                    locked=c.estimator.locked,
                    alive=peer.alive,
                    samples=c.accepted,
                    sent=c.sent,
                    timeouts=c.timeouts,
                    rejected=sum(c.rejected.values()),
                    rejected_by_reason=dict(c.rejected),
                )
        return Status(
            agent=str(self.me),
            federation=self.config.federation,
            role=self.config.role,
            reference=str(self.reference),
            t_exec=t_exec,
            host_monotonic=host,
            t_sim=self.sim_time(t_exec),
            pose=list(self.pose),
            peers=peers,
            counters=self.counter_snapshot(),
        )

    def counter_snapshot(self) -> dict[str, int]:
        with self._count_lock:
            return dict(self.counters)

    def _flush_records(self) -> None:
        """Write recorded lines from the agent's loop, never from a callback."""
        with self._lock:
            records, self._records = self._records, []
            poses, self._pose_records = self._pose_records, []
        for f, lines in ((self._record_file, records), (self._pose_file, poses)):
            if f is not None and lines:
                f.write("".join(lines))
                f.flush()

    def publish_status(self) -> None:
        self._flush_records()
        line = self.status().model_dump_json()
        self._status_pub.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)
        if self._status_file is not None:
            self._status_file.write(line + "\n")
            self._status_file.flush()

    # -- Zenoh callbacks: quick, and never raise -----------------------------
    def _on_sync_query(self, query: zenoh.Query) -> None:
        t2 = self.clock.now()  # read on arrival: the paper's t2
        try:
            payload = query.payload
            try:
                t1 = wire.decode_request(payload.to_bytes() if payload is not None else b"")
            except wire.DecodeError as error:
                self.count("sync_requests_malformed")
                self.rejects("sync request", f"{query.key_expr}: {error}")
                return
            reply = wire.encode_reply(t1, t2, self.pose)
            # The send time rides in the attachment: the payload stays the paper's 64 bytes.
            t2s = wire.encode_request(self.clock.now())
            query.reply(query.key_expr, reply, attachment=t2s)
            self.count("sync_requests_served")
        except Exception:
            log.exception("sync query on %s failed", query.key_expr)
        finally:
            query.drop()  # type: ignore[no-untyped-call]  # release now, or the querier waits

    def _on_sync_reply(self, peer: Peer, reply: zenoh.Reply) -> None:
        t3, host = self.clock.read()  # read on arrival: the paper's t3
        try:
            if reply.ok is None:
                self.count("sync_reply_errors")
                return
            t2s = None
            if self.config.four_timestamps and reply.ok.attachment is not None:
                try:
                    t2s = wire.decode_request(reply.ok.attachment.to_bytes())
                except wire.DecodeError:
                    self.count("sync_attachment_malformed")
            with self._lock:
                accepted = peer.client.receive(reply.ok.payload.to_bytes(), t3, t2s)
                reason = peer.client.last_rejection
                if accepted is not None and self._record_file is not None:
                    self._records.append(
                        f'{{"peer": "{peer.agent}", "t1": {accepted.t1!r}, "t2": {accepted.t2!r}, '
                        f'"t3": {t3!r}, "t2s": {"null" if t2s is None else repr(t2s)}, '
                        f'"host_monotonic": {host!r}}}\n'
                    )
            if accepted is None:
                self.rejects(f"sync reply ({reason})", f"from {peer.key}")
        except Exception:
            log.exception("sync reply from %s failed", peer.key)

    def _on_pose(self, sample: zenoh.Sample) -> None:
        t_recv, host = self.clock.read()
        try:
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            try:
                decoded = wire.decode_pose(sample.payload.to_bytes())
            except wire.DecodeError as error:
                self.count("pose_malformed")
                self.rejects("pose sample", f"{sample.key_expr}: {error}")
                return
            self.count("pose_received")
            if parsed is not None:
                self.latest_poses[parsed[0]] = decoded
            if self._pose_file is not None:
                line = (
                    f'{{"agent": "{parsed[0] if parsed else ""}", "t": {decoded.t!r}, '
                    f'"t_recv": {t_recv!r}, "host_monotonic": {host!r}}}\n'
                )
                with self._lock:
                    self._pose_records.append(line)
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            if parsed is None or parsed[1] is not None or parsed[0] == self.me:
                return
            agent = parsed[0]
            alive = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                peer = self.peers.get(agent)
                if peer is None:
                    if not alive:
                        return
                    peer = self.peers[agent] = Peer(
                        agent, self._new_client(), self.key(agent, "sync")
                    )
                elif alive and not peer.alive:
                    peer.client.reset()  # a restarted agent has a new clock
                peer.alive = alive
            log.info("agent %s %s", agent, "joined" if alive else "left")
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)

    def _new_client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), timeout=cfg.sync_timeout)


Agent = AgentRuntime


def _open_append(path: Path | None) -> IO[str] | None:
    if path is None:
        return None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.open("a", encoding="utf-8")


def _next_tick(previous: float, period: float, now: float) -> float:
    """Next deadline on the period's grid; skip missed ticks instead of bursting."""
    tick = previous + period
    return tick if tick > now else now + period

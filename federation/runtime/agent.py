"""Agent runtime: the thin Zenoh layer around the sync client, guidance, run state and
a platform.

Threads and who owns what:

- Zenoh's network thread runs the callbacks (``indirect=False``): the sync
  queryable reads ``t2`` and replies at once; a sync reply reads ``t3`` and is
  matched under ``_lock``; pose, liveliness and control samples are decoded and
  stored. Callbacks never raise and never block: a bad payload is logged and
  counted.
- The agent's own loop (``run``) steps the platform, publishes pose and status
  and sends sync requests (``session.get`` with a callback returns at once).
  Agents hosted in one process may share that thread (:func:`run_together`).
- A recorder thread writes the MCAP file (:mod:`federation.runtime.recorder`).

The decisions are made in the pure core: run modes (:mod:`federation.core.runstate`),
time bases (:mod:`federation.core.timebase`), the sync exchange's two halves
(:mod:`federation.core.sync`), the stale-link hold (:mod:`federation.core.linkwatch`)
and the periodic tasks' deadlines (:mod:`federation.core.schedule`, run by
:mod:`federation.runtime.loop`). :func:`run_together`, :class:`Schedule` and
:func:`peer_status` are importable from here as before.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import zenoh
from pydantic import ValidationError

from agents.guidance import ReferenceManeuver, track_heading
from agents.platform import Platform, make_platform
from federation.core import keys, wire
from federation.core.channels import Channel
from federation.core.estimators import make_estimator
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch
from federation.core.runstate import Event, RunState
from federation.core.schedule import next_tick
from federation.core.sync import SyncClient, read_send_time, serve
from federation.core.timebase import TimeBase
from federation.runtime.clock import ExecClock
from federation.runtime.fanout import Fanout
from federation.runtime.loop import Schedule, run_together
from federation.runtime.recorder import Recorder
from federation.runtime.status import loop_stats, peer_status
from schemas.config import AgentConfig, ManeuverConfig
from schemas.messages import Command, Status
from schemas.platform import PlatformConfig

if TYPE_CHECKING:
    from agents.analysis import Margins  # imports python-control: only for a physical platform

__all__ = ["AgentRuntime", "NameTaken", "Schedule", "peer_status", "run_together"]

log = logging.getLogger("fedlab.agent")


class NameTaken(ValueError):
    """Another agent already uses this lab/name in the federation."""


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
    querier: Any = None  # zenoh.Querier on the peer's sync key, declared on first use
    on_reply: Any = None  # its reply handler, made once
    next_sync: float = 0.0  # host monotonic time of its next sync request

    def offset_at(self, t: float) -> float | None:
        """Its clock minus this agent's at own time ``t`` (s): the time base's estimate."""
        return self.client.offset_at(t)


class AgentRuntime:
    """One agent on an open Zenoh session. ``start()``, ``run(stop)``, ``close()``."""

    def __init__(
        self,
        config: AgentConfig,
        session: zenoh.Session,
        clock: ExecClock | None = None,
        platform: Platform | None = None,
        maneuver: Callable[[float], tuple[float, float]] | None = None,
        fanout: Fanout | None = None,
    ):
        self.config = config
        self.session = session
        self.fanout = fanout  # shared pose subscriptions of agents on one session
        self.me = config.agent
        self.clock = clock or ExecClock(config.clock_offset, config.clock_drift_ppm)
        self.platform: Platform = platform or make_platform(
            config.platform, config.seed, rate=config.pose_rate, preset=config.platform_preset
        )
        self.maneuver = maneuver or _maneuver(config.maneuver)
        self.follow = AgentId.parse(config.follow) if config.follow else None
        if config.reference is not None:
            self.reference = AgentId.parse(config.reference)
        elif config.role == "follower" and self.follow is not None:
            self.reference = self.follow
        else:
            self.reference = self.me
        self.explicit_sync = {AgentId.parse(a) for a in config.sync_with}
        if self.explicit_sync and self.follow:
            self.explicit_sync.add(self.follow)
        # Queried every sync_period; every other agent alive only every
        # sync_others_period, so a leader's load does not grow tenfold with N.
        self.close_sync = self.explicit_sync or {
            a for a in (self.reference, self.follow) if a is not None and a != self.me
        }
        self.run_state = RunState(autostart=not config.wait_start)
        self.pose = wire.Pose()
        self.guidance = (0.0, 0.0)  # last heading and rate references
        # When they were computed: t_exec, host monotonic, t_sim, run time.
        self.guidance_at: tuple[float, float, float | None, float | None] = (0.0, 0.0, None, None)
        self.peers: dict[AgentId, Peer] = {}
        # Own clock <-> reference time <-> a peer's clock, through the peers' estimates.
        self.timebase = TimeBase(self.me, self.reference, self.peers)
        self.latest_poses: dict[AgentId, wire.PoseSample] = {}
        self.pose_received_at: dict[AgentId, float] = {}  # own clock at arrival
        self.hold_reason: str | None = None  # "stale" or "aborted" while valves are held
        self.link_watch = LinkWatch(config.stale_after)
        self._clock_stepped = False
        self.counters: Counter[str] = Counter()
        self.lateness: deque[float] = deque(maxlen=2000)  # control ticks' lateness (s)
        self.rejects = RateLimitedLog(log)
        self.recorder = (
            Recorder(config.record, str(self.me), config.record_channels) if config.record else None
        )
        self.margins = _margins(self.platform)
        self._delay_warned = False
        self._count_lock = threading.Lock()
        self._lock = threading.Lock()
        self._declared: list[Any] = []
        self._status_file: IO[str] | None = None
        self._pose_pub: Any = None
        self._status_pub: Any = None

    def count(self, name: str) -> None:
        """Bump a counter; callbacks may run on several Zenoh threads at once."""
        with self._count_lock:
            self.counters[name] += 1

    def recording(self, topic: Channel) -> bool:
        """Whether ``topic`` is recorded: callbacks build no message otherwise."""
        return self.recorder is not None and topic in self.recorder.channels

    def record(self, topic: Channel, message: dict[str, Any]) -> None:
        if self.recorder is not None:
            self.recorder.record(topic, message)

    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> None:
        """Declare everything; refuse (NameTaken) if the name is already in the federation."""
        s = self.session
        callback = zenoh.handlers.Callback
        fed = self.config.federation
        self._refuse_taken_name()
        self._declared.append(
            s.declare_queryable(
                self.key(self.me, "sync"), callback(self._on_sync_query, indirect=False)
            )
        )
        self._pose_pub = s.declare_publisher(self.key(self.me, "pose"), express=True)
        self._status_pub = s.declare_publisher(self.key(self.me, "status"))
        self._declared += [self._pose_pub, self._status_pub]
        watched = keys.all_of(fed, "pose") if self.config.watch_all else None
        if watched is None and self.follow is not None:
            watched = self.key(self.follow, "pose")
        if watched is not None:
            self._declared.append(
                self.fanout.subscribe(watched, self._on_pose)
                if self.fanout is not None
                else s.declare_subscriber(watched, callback(self._on_pose, indirect=False))
            )
        self._declared.append(
            s.declare_subscriber(keys.control_key(fed), callback(self._on_control, indirect=False))
        )
        self._declared.append(
            s.liveliness().declare_subscriber(
                keys.all_agents(fed), callback(self._on_liveliness, indirect=False), history=True
            )
        )
        self._declared.append(s.liveliness().declare_token(self.key(self.me)))
        if self.config.status_json is not None:
            path = Path(self.config.status_json)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._status_file = path.open("a", encoding="utf-8")
        log.info("agent %s (%s) up in federation %s", self.me, self.config.role, fed)

    def _refuse_taken_name(self) -> None:
        """Two agents may not share a name: ask liveliness whether ours is alive."""
        replies = self.session.liveliness().get(self.key(self.me), timeout=1.0)
        for reply in replies:
            if reply.ok is not None:
                raise NameTaken(
                    f"agent {self.me} is already in federation {self.config.federation}: "
                    "stop it first or choose another --name"
                )

    def others(self) -> dict[str, tuple[float, wire.Pose]]:
        """Every other agent's latest pose, stamped on simulation (reference) time:
        its own clock mapped through this agent's offset estimates (Eq. 5)."""
        out = {}
        t_exec = self.clock.now()
        for agent, sample in list(self.latest_poses.items()):
            if agent == self.me:  # watching every pose, its own comes back too
                continue
            t_sim = self.timebase.peer_to_sim(agent, sample.t, t_exec)
            if t_sim is not None:
                out[str(agent)] = (t_sim, sample.pose)
        return out

    def close(self) -> None:
        """Undeclare everything (tokens and subscribers first); the caller closes the session."""
        self.platform.hold()  # leave the platform with every valve closed
        try:
            self.platform.close()  # a serial platform sends all-closed and releases its port
        except Exception as error:
            log.warning("closing the platform failed: %s", error)
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception as error:  # a session already closed by zenoh
                log.debug("undeclare failed: %s", error)
        self._declared.clear()
        if self._status_file is not None:
            self._status_file.close()
            self._status_file = None
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None

    def run(self, stop: threading.Event) -> None:
        """The agent's loop, until ``stop`` is set or the configured duration has passed.

        Periodic tasks on one thread: the platform's control step (its ``rate``,
        100 Hz for simulated platforms), pose publication (``pose_rate``), sync
        requests (``sync_period``) and status (``status_period``). A missed tick is
        skipped, not made up, and counted in ``loop_overruns``. An armed start is a
        deadline of its own, so the run begins on time, not at the next tick.
        """
        run_together([self], stop)

    # -- time --------------------------------------------------------------------------
    def reference_offset(self, t_exec: float) -> float | None:
        """Reference clock minus own clock (0 on the reference itself)."""
        return self.timebase.reference_offset(t_exec)

    def sim_time(self, t_exec: float) -> float | None:
        """Simulation time (Eq. 5): the reference agent's clock."""
        return self.timebase.sim_time(t_exec)

    def start_due(self) -> float:
        """Host monotonic time at which an armed run starts (inf if none is armed)."""
        start_at = self.run_state.start_at
        if self.run_state.mode != "armed" or start_at is None:
            return math.inf
        t_exec, host = self.clock.read()
        t_sim = self.timebase.sim_time(t_exec)
        if t_sim is None:
            return math.inf
        return host + (start_at - t_sim) / self.clock.rate

    # -- the agent's own loop ----------------------------------------------------------
    def reference_heading(self, t_exec: float, run_time: float | None) -> tuple[float, float]:
        """Guidance: the leader's maneuver on run time, or the followed heading."""
        if self.config.role == "leader":
            return (0.0, 0.0) if run_time is None else self.maneuver(run_time)
        if self.config.role == "member":
            return 0.0, 0.0  # its pose source decides where it goes
        received = self.latest_poses.get(self.follow) if self.follow else None
        # The followed agent's clock now: its samples are stamped on it.
        now = self.timebase.peer_time(self.follow, t_exec) if self.follow else None
        return track_heading(received, now, self.config.latency_compensation)

    def control_step(self) -> None:
        """Run state, link watch, guidance and one platform step (the platform's rate)."""
        self._rehearse_clock_step()
        t_exec, host = self.clock.read()
        t_sim = self.sim_time(t_exec)
        with self._lock:
            events = self.run_state.update(t_sim)
            run_time = self.run_state.run_time(t_sim)
        self._apply(events, t_exec, host)
        self._watch_link(t_exec, host)
        self.guidance = self.reference_heading(t_exec, run_time)
        self.guidance_at = (t_exec, host, t_sim, run_time)
        self.pose = self.platform.step(t_exec, *self.guidance)

    def _watch_link(self, t_exec: float, host: float) -> None:
        """Safe hold while the followed pose is stale; resume once it flows again and a
        sync exchange has completed since (re-synchronized). An abort overrides it."""
        if self.follow is None or self.hold_reason == "aborted":
            return
        received = self.pose_received_at.get(self.follow)
        peer = self.peers.get(self.follow)
        last = peer.client.last if peer else None
        action = self.link_watch.update(t_exec, received, None if last is None else last.t3)
        if action == "stale_hold" and received is not None:
            self.hold_reason = "stale"
            self.platform.hold()
            self.count("stale_holds")
            log.warning(
                "no pose from %s for %.0f ms: safe hold", self.follow, (t_exec - received) * 1e3
            )
            self._event("stale_hold", t_exec, host, f"last pose {t_exec - received:.3f} s ago")
        elif action == "link_resumed":
            self.hold_reason = None
            self.platform.release()
            log.info("pose from %s flows again and sync resumed: released", self.follow)
            self._event("link_resumed", t_exec, host, "")

    def _rehearse_clock_step(self) -> None:
        step = self.config.clock_step
        if step is not None and not self._clock_stepped and self.clock.now() >= step[0]:
            self._clock_stepped = True
            self.clock.step(step[1])
            log.warning("rehearsal: the execution clock jumps %+.3f s", step[1])

    def _event(self, kind: str, t_exec: float, host: float, detail: str) -> None:
        self.record(
            Channel.CONTROL,
            {
                "event": kind,
                "command": None,
                "at": None,
                "t_exec": t_exec,
                "t_sim": self.sim_time(t_exec),
                "host_monotonic": host,
                "mode": self.run_state.mode,
                "detail": detail,
            },
        )

    def publish_pose(self) -> None:
        t_exec, host = self.clock.read()
        self._pose_pub.put(wire.encode_pose(t_exec, self.pose))
        if self.recorder is not None:
            stamp = {"t_exec": t_exec, "host_monotonic": host}
            self.record(Channel.POSE_SENT, stamp | self.pose._asdict())
            # The reference as computed at the last control step, stamped with that step's time.
            g_exec, g_host, g_sim, g_run = self.guidance_at
            self.record(
                Channel.REFERENCE,
                {
                    "t_exec": g_exec,
                    "host_monotonic": g_host,
                    "t_sim": g_sim,
                    "run_time": g_run,
                    "heading_ref": self.guidance[0],
                    "rate_ref": self.guidance[1],
                    "mode": self.run_state.mode,
                    "valves_open": sum(getattr(self.platform, "valves", ())),
                },
            )
            truth = getattr(self.platform, "truth", None)
            if truth is not None:
                self.record(Channel.TRUTH, stamp | truth._asdict())

    def step(self) -> None:
        """One control step, then publish the pose."""
        self.control_step()
        self.publish_pose()

    def _apply(self, events: list[Event], t_exec: float, host: float) -> None:
        """Act on run-state events: safe hold on abort; log and record each."""
        for event in events:
            if event.kind == "aborted":
                self.hold_reason = "aborted"
                self.platform.hold()
            level = logging.WARNING if event.kind in ("aborted", "ignored") else logging.INFO
            log.log(level, "run %s at reference time %s %s", event.kind, event.t_sim, event.detail)
            self.record(
                Channel.CONTROL,
                {
                    "event": event.kind,
                    "command": None,
                    "at": self.run_state.start_at,
                    "t_exec": t_exec,
                    "t_sim": event.t_sim,
                    "host_monotonic": host,
                    "mode": self.run_state.mode,
                    "detail": event.detail,
                },
            )

    def due_for_sync(self, now: float) -> list[AgentId]:
        """The agents due for a sync request at host monotonic time ``now``, each
        scheduled for its next one: those in ``sync_with`` (or, when it is empty, the
        reference and the followed agent) every ``sync_period``; with an empty
        ``sync_with``, every other agent alive every ``sync_others_period`` on its own
        phase."""
        cfg = self.config
        due = []
        for agent, peer in list(self.peers.items()):  # liveliness may add one meanwhile
            if not peer.alive or (self.explicit_sync and agent not in self.explicit_sync):
                continue
            if peer.next_sync > now:
                continue
            if agent in self.close_sync:
                peer.next_sync = now + 0.5 * cfg.sync_period  # due again at the next tick
            else:
                peer.next_sync = next_tick(peer.next_sync, cfg.sync_others_period, now)
            due.append(agent)
        return due

    def send_sync_requests(self, now: float | None = None) -> None:
        """Query every agent due at host monotonic ``now`` (default: the present)."""
        for agent in self.due_for_sync(time.monotonic() if now is None else now):
            peer = self.peers[agent]
            try:
                if peer.querier is None:
                    # One querier and one handler per peer: a query costs a single call.
                    peer.querier = self.session.declare_querier(
                        peer.key,
                        consolidation=zenoh.ConsolidationMode.NONE,
                        timeout=self.config.sync_timeout,
                        express=True,
                    )
                    self._declared.append(peer.querier)
                    peer.on_reply = zenoh.handlers.Callback(
                        functools.partial(self._on_sync_reply, peer), indirect=False
                    )
                with self._lock:
                    payload = peer.client.request(self.clock.now())
                peer.querier.get(peer.on_reply, payload=payload)
            except Exception as error:  # session closing, or zenoh refusing the query
                log.warning("sync request to %s failed: %s", agent, error)

    # -- status ------------------------------------------------------------------------
    def status(self) -> Status:
        t_exec, host = self.clock.read()
        peers = {}
        with self._lock:
            for agent, peer in self.peers.items():
                if peer.client.sent:  # agents this one has never queried: nothing to say
                    peers[str(agent)] = peer_status(peer.client, t_exec, peer.alive)
        t_sim = self.sim_time(t_exec)
        received = self.latest_poses.get(self.follow) if self.follow else None
        # Its samples are stamped on its clock: their age is measured on it.
        follow_now = self.timebase.peer_time(self.follow, t_exec) if self.follow else None
        pose_age = None if received is None or follow_now is None else follow_now - received.t
        return Status(
            agent=str(self.me),
            federation=self.config.federation,
            role=self.config.role,
            reference=str(self.reference),
            t_exec=t_exec,
            host_monotonic=host,
            t_sim=t_sim,
            mode=self.run_state.mode,
            run_time=self.run_state.run_time(t_sim),
            platform=self.config.platform,
            follow=None if self.follow is None else str(self.follow),
            hold=self.hold_reason,
            pose_age=pose_age,
            pose=list(self.pose),
            peers=peers,
            counters=self.counter_snapshot(),
            loop=self.loop_stats(),
        )

    def loop_stats(self) -> dict[str, float]:
        """Control loop timing: rate and lateness of the recent ticks (ms)."""
        return loop_stats(self.platform.rate, list(self.lateness))

    def counter_snapshot(self) -> dict[str, int]:
        with self._count_lock:
            return dict(self.counters)

    def check_delay_margin(self, status: Status) -> None:
        """Warn once when the followed link's delay exceeds a quarter of the loop's delay
        margin (``fedlab analyze``); again if it recovers and crosses once more."""
        if self.margins is None or self.follow is None:
            return
        view = status.peers.get(str(self.follow))
        delay = None if view is None else view.delay
        warning = None if delay is None else self.margins.warn(delay)
        if warning and not self._delay_warned:
            log.warning("%s", warning)
        self._delay_warned = warning is not None

    def publish_status(self) -> None:
        status = self.status()
        self.check_delay_margin(status)
        line = status.model_dump_json()
        self._status_pub.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)
        if self._status_file is not None:
            self._status_file.write(line + "\n")
            self._status_file.flush()
        self.record(Channel.STATUS, status.model_dump())

    # -- Zenoh callbacks: quick, and never raise ---------------------------------------
    def _on_sync_query(self, query: zenoh.Query) -> None:
        t2 = self.clock.now()  # read on arrival: the paper's t2
        try:
            payload = query.payload
            request = payload.to_bytes() if payload is not None else b""
            try:
                # The send time rides in the attachment: the payload stays the paper's 64 bytes.
                served = serve(request, t2, self.pose, self.clock.now())
            except wire.DecodeError as error:
                self.count("sync_requests_malformed")
                self.rejects("sync request", f"{query.key_expr}: {error}")
                return
            query.reply(query.key_expr, served.payload, attachment=served.attachment)
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
                    t2s = read_send_time(reply.ok.attachment.to_bytes())
                except wire.DecodeError:
                    self.count("sync_attachment_malformed")
            with self._lock:
                steps = peer.client.steps
                accepted = peer.client.receive(reply.ok.payload.to_bytes(), t3, t2s)
                reason = peer.client.last_rejection
                exchange = peer.client.last
                recorded = self.recording(Channel.SYNC_EXCHANGE)
                estimate = peer.client.offset_at(t3) if recorded else None
                stepped = peer.client.steps > steps
            if stepped:
                self.count("clock_steps")
                jump = peer.client.last_step or 0.0
                log.warning(
                    "clock step of %+.3f s between %s and %s: estimate reset",
                    jump,
                    self.me,
                    peer.agent,
                )
                self._event("clock_step", t3, host, f"{peer.agent}: {jump:+.6f} s")
            if accepted is None or exchange is None:
                self.rejects(f"sync reply ({reason})", f"from {peer.key}")
                return
            if not recorded:
                return
            self.record(
                Channel.SYNC_EXCHANGE,
                {
                    "peer": str(peer.agent),
                    "t1": exchange.t1,
                    "t2": exchange.t2,
                    "t3": exchange.t3,
                    "t2s": exchange.t2s,
                    "offset": exchange.offset,
                    "delay": exchange.delay,
                    "estimate": estimate,
                    "host_monotonic": host,
                },
            )
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
                self.pose_received_at[parsed[0]] = t_recv
            if not self.recording(Channel.POSE_RECEIVED):
                return
            self.record(
                Channel.POSE_RECEIVED,
                {
                    "agent": str(parsed[0]) if parsed else str(sample.key_expr),
                    "t": decoded.t,
                    "t_recv": t_recv,
                    "host_monotonic": host,
                    **decoded.pose._asdict(),
                },
            )
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_control(self, sample: zenoh.Sample) -> None:
        t_exec, host = self.clock.read()
        try:
            try:
                command = Command.model_validate_json(sample.payload.to_bytes())
            except ValidationError as error:
                self.count("control_malformed")
                self.rejects("control command", f"{sample.key_expr}: {error.errors()[0]['msg']}")
                return
            self.count("control_received")
            with self._lock:
                events = self.run_state.command(command, self.sim_time(t_exec))
                if command.maneuver is not None and any(e.kind == "armed" for e in events):
                    self.maneuver = _maneuver(command.maneuver)
            self.record(
                Channel.CONTROL,
                {
                    "event": "command",
                    "command": command.model_dump(),
                    "at": command.at,
                    "t_exec": t_exec,
                    "t_sim": self.sim_time(t_exec),
                    "host_monotonic": host,
                    "mode": self.run_state.mode,
                    "detail": "",
                },
            )
            self._apply(events, t_exec, host)
        except Exception:
            log.exception("control sample on %s failed", sample.key_expr)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            if parsed is None or parsed[1] is not None or parsed[0] == self.me:
                return
            self.peer_seen(parsed[0], sample.kind == zenoh.SampleKind.PUT)
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)

    def peer_seen(self, agent: AgentId, alive: bool) -> None:
        """Liveliness news of another agent: joined (``alive``) or left."""
        with self._lock:
            peer = self.peers.get(agent)
            if peer is None:
                if not alive:
                    return
                peer = self.peers[agent] = Peer(
                    agent, self._new_client(), self.key(agent, "sync"),
                    next_sync=self._first_sync(agent, len(self.peers)),
                )  # fmt: skip
            elif alive and not peer.alive:
                peer.client.reset()  # a restarted agent has a new clock
                peer.next_sync = self._first_sync(agent, len(self.peers))
            peer.alive = alive
        log.info("agent %s %s", agent, "joined" if alive else "left")

    def _first_sync(self, agent: AgentId, index: int) -> float:
        """When the ``index``-th peer seen gets its first request: at once for the ones
        synced every period, else spread over ``sync_others_period`` (golden-ratio
        phases, so no tick carries a burst however many agents join)."""
        if agent in self.close_sync:
            return 0.0
        phase = (index * 0.6180339887498949) % 1.0
        return time.monotonic() + phase * self.config.sync_others_period

    def _new_client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), timeout=cfg.sync_timeout)


def _margins(platform: Platform) -> Margins | None:
    """Heading-loop margins of a platform that has a physical description."""
    config: PlatformConfig | None = platform.config
    if config is None:
        return None
    from agents.analysis import heading_margins

    try:
        return heading_margins(config)
    except ValueError as error:
        log.warning("no delay margin for %s: %s", config.name, error)
        return None


def _maneuver(m: ManeuverConfig) -> ReferenceManeuver:
    return ReferenceManeuver(m.still, m.duration, math.radians(m.amplitude_deg))

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

import dataclasses
import functools
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import zenoh
from pydantic import ValidationError

from agents.guidance import ReferenceManeuver, Track, track_heading
from agents.platform import Platform, make_platform
from agents.scenario import ScenarioGuidance, make_scenario
from federation.core import keys, wire
from federation.core.channels import Channel
from federation.core.commands import CommandGate, Verdict
from federation.core.contest import Channel as ContestChannel
from federation.core.contest import ContestWatch, in_order
from federation.core.estimators import make_estimator
from federation.core.holds import Hold, Trigger
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch, SilenceWatch
from federation.core.ring import FloatRing
from federation.core.runstate import Event, RunState
from federation.core.schedule import next_tick
from federation.core.sync import SyncClient, read_send_time, serve
from federation.core.timebase import TimeBase
from federation.runtime.clock import ExecClock
from federation.runtime.collect import RecordingServer, manifest_name
from federation.runtime.fanout import Fanout, Received
from federation.runtime.links import PoseFeed, SyncLink, SyncLinks
from federation.runtime.loop import Schedule, run_together
from federation.runtime.names import (
    NAME_CHECKS_AFTER,
    NameTaken,
    clash_message,
    look_again,
    name_alive,
)
from federation.runtime.recorder import Message, Recorder, Shared
from federation.runtime.runs import (
    PROMISES,
    RunRecording,
    low_space,
    recording_budget,
    software_versions,
)
from federation.runtime.safety import Safety
from federation.runtime.session import undeclare_all
from federation.runtime.status import loop_stats, peer_status
from schemas.config import AgentConfig, ManeuverConfig
from schemas.messages import (
    Command,
    CommandOutcome,
    Readiness,
    Status,
    is_abort,
    malformed_outcome,
    validation_reason,
)
from schemas.platform import PlatformConfig

if TYPE_CHECKING:
    from agents.analysis import Margins  # imports python-control: only for a physical platform

__all__ = ["AgentRuntime", "NameTaken", "Schedule", "peer_status", "run_together"]

log = logging.getLogger("fedlab.agent")

NO_ROUTER_HOLD = 1.0
"""s without a router (after having one) before an agent holds (``no_router``)."""
ROUTER_CHECK_PERIOD = 0.25
"""s between looks at the session's router."""
_ACTIVE = frozenset({"armed", "running", "frozen"})
"""Run modes in which a run is under way."""
_LOCAL_ABORT = Command(command="abort", seq=-1, issuer="fedlab (this agent)")
"""The abort an agent gives itself (its reference restarted mid-run)."""
_RUN_TRIGGERS = {
    "armed": Trigger.RUN_ARMED,
    "started": Trigger.RUN_STARTED,
    "done": Trigger.RUN_DONE,
    "aborted": Trigger.RUN_ABORTED,
}
"""The run state's events that the safety supervisor hears (a reset is heard as the
operator's command, applied: :meth:`AgentRuntime._on_control`)."""
MAX_SMALL_PAYLOAD = 1024
"""Bytes: a pose sample is 56, a sync request 8 and its reply 64; a payload larger than
this on those keys is junk, dropped and counted before it is copied (issue 13)."""


def _fix_check(platform: Any) -> Callable[[], bool] | None:
    """How to ask ``platform`` whether its estimate rests on a metrology fix yet (None:
    it has no filter to ask)."""
    if hasattr(platform, "has_fix"):
        return lambda: bool(platform.has_fix)
    chain = getattr(platform, "chain", None)
    if chain is not None and hasattr(chain, "fix_time"):
        return lambda: chain.fix_time is not None
    return None


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


@dataclass(slots=True)  # one per agent seen, in every agent: no __dict__ each
class Peer:
    """Another agent as this one knows it: alive or not and, if this agent queries it,
    the sync link whose estimate of its clock it reads (its own, or shared with the
    agents of its process on the same clock: :mod:`federation.runtime.links`).

    An agent not queried has no link, hence no estimate (issue 17: a follower among
    256 agents queries two of them, and a link to each of the others made a
    federation's memory grow as N squared)."""

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
        links: SyncLinks | None = None,
    ):
        self.config = config
        self.session = session
        self.fanout = fanout  # shared pose subscriptions of agents on one session
        # Sync links: shared with the agents of this session on the same clock object.
        self.links = links if links is not None else SyncLinks()
        self.me = config.agent
        self.clock = clock or ExecClock(config.clock_offset, config.clock_drift_ppm)
        self.platform: Platform = platform or make_platform(
            config.platform, config.seed, rate=config.pose_rate, preset=config.platform_preset
        )
        self.maneuver = maneuver or _maneuver(config.maneuver)
        self.follow = AgentId.parse(config.follow) if config.follow else None
        self._follow_name = None if self.follow is None else str(self.follow)
        # Issue 14's hook: a formation, docking or adaptive-gain part (agents.scenario)
        # gives the 3-DOF reference; its platform takes and gives the common frame.
        self.scenario: ScenarioGuidance | None = None
        if config.scenario is not None:
            self.scenario = make_scenario(
                str(self.me), config.scenario, self.platform,
                None if self.follow is None else str(self.follow), config.latency_compensation,
            )  # fmt: skip
            self.platform = self.scenario.platform
        # Whether the platform's estimate rests on a fix (None: it has no filter, as a
        # kinematic one): before its first fix a filter's estimate is only its prior.
        self._has_fix = _fix_check(self.platform)
        self.track: Track | None = None  # the last position reference, common frame
        # The run (id, start) the scenario's guidance is for.
        self._scenario_run: tuple[str | None, float | None] | None = None
        self._scenario_new_run = False
        self._status_now = False  # a command was applied: report it at the next step
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
        # One reference time (issue 17): every pose carries its reference time
        # (wire.encode_stamp), so an agent syncs only with its reference and the agent it
        # follows; the reference itself (a monitor of every clock) or one with sync_all
        # also queries every other agent each sync_others_period. Sync traffic is O(N).
        self.sync_all = config.sync_all or self.reference == self.me
        self.ref_id = wire.reference_id(str(self.reference))
        self.pairwise: set[AgentId] = set()  # senders of poses without our reference stamp
        # The latest stamped pose of each peer: (its t, t_ref, bound).
        self.latest_ref: dict[AgentId, tuple[float, float, float]] = {}
        self._next_sync_due = 0.0  # host monotonic: no peer is due before it
        self._pose_keys: dict[str, tuple[AgentId, str | None] | None] = {}
        self.run_state = RunState(autostart=not config.wait_start, duration=config.run_duration)
        self.gate = CommandGate()  # which commands to act on: per issuer, aborts always
        self.command_log: deque[CommandOutcome] = deque(maxlen=8)
        self.pose = wire.Pose()
        self.guidance = (0.0, 0.0)  # last heading and rate references
        # When they were computed: t_exec, host monotonic, t_sim, run time.
        self.guidance_at: tuple[float, float, float | None, float | None] = (0.0, 0.0, None, None)
        self.peers: dict[AgentId, Peer] = {}
        # Own clock <-> reference time <-> a peer's clock, through the peers' estimates.
        self.timebase = TimeBase(self.me, self.reference, self.peers)
        self.latest_poses: dict[AgentId, wire.PoseSample] = {}
        # Each peer's last pose taken: (its source, its t). One from that source no newer
        # is dropped (a reordered or repeated sample); forgotten when the peer leaves.
        self._pose_order: dict[AgentId, tuple[str | None, float]] = {}
        self._pose_lock = threading.Lock()  # the order and the latest pose, together
        self.pose_received_at: dict[AgentId, float] = {}  # own clock at arrival
        # Every hold and release: the supervisor's table (federation.core.holds).
        self.safety = Safety(self.platform)
        self.link_watch = LinkWatch(config.stale_after)
        # The followed agent's poses, admitted once for the agents of this session that
        # follow it on one sync link (federation.runtime.links); None: handled here.
        self.feed: PoseFeed | None = None
        # Two sources speaking for one peer: nothing from it is used (issue 13).
        self.contest = ContestWatch()
        self._contest_lock = threading.Lock()
        self._contest_cleared: float | None = None  # own time a followed contest cleared
        self._reference_zid: str | None = None  # the session last heard for the reference
        # The session's router: had one, lost since (host monotonic), next look.
        self._had_router = False
        self._router_lost: float | None = None
        self._router_check = 0.0
        self._pose_sn = 0  # sequence number in the pose samples' source info
        self.silence = SilenceWatch()  # peers alive that answer no sync request
        self._silent_warned: set[str] = set()  # peers' names
        self._clock_stepped = False
        self._left_area = False  # the scenario's platform left its area (held for good)
        # Host monotonic times of the later looks at the name (start + NAME_CHECKS_AFTER),
        # the next first; why the name is taken twice, once a look found another holder.
        self._name_checks: list[float] = []
        self.name_clash: str | None = None
        self.counters: Counter[str] = Counter()
        self.lateness = FloatRing(2000)  # control ticks' lateness (s)
        self.rejects = RateLimitedLog(log)
        self.recorder: Recorder | None = None
        if config.record:  # a peer publishing far too fast fills no disk here either
            config.record.parent.mkdir(parents=True, exist_ok=True)
            # The budget of the disk written: a symlinked FILE's target's, not the link's.
            where = config.record.resolve().parent
            where.mkdir(parents=True, exist_ok=True)  # a link to a folder not yet made
            _, budget = recording_budget(where, config.record_max_mb, self)
            try:
                self.recorder = Recorder(
                    config.record, str(self.me), config.record_channels, max_bytes=budget
                )
            except BaseException:  # no recording: nothing promised (to any process)
                PROMISES.give_back(where, self)
                raise
        self.run_recording: RunRecording | None = None  # this run's, under runs_dir
        self.finishing: list[threading.Thread] = []  # recordings finishing after a close
        self._closing = False
        # The channels recorded now (the file's and the run's): read on every message.
        self._recorded: frozenset[str] = frozenset()
        self._update_recorded()
        self.recording_server: RecordingServer | None = None
        self.margins = _margins(self.platform)
        self._delay_warned = False
        self._count_lock = threading.Lock()
        self._lock = threading.Lock()  # taken after the safety lock when both are
        self._declared: list[Any] = []
        self._status_file: IO[str] | None = None
        self._pose_pub: Any = None
        self._pose_pub_id: Any = None
        self._status_pub: Any = None

    def count(self, name: str) -> None:
        """Bump a counter; callbacks may run on several Zenoh threads at once."""
        with self._count_lock:
            self.counters[name] += 1

    def recording(self, topic: Channel) -> bool:
        """Whether ``topic`` is recorded: callbacks build no message otherwise."""
        return topic in self._recorded

    def _update_recorded(self) -> None:
        """Gather the recorded channels again (a recorder opened or closed): one set,
        read by every callback, rather than two recorders' (issue 17: a lean agent)."""
        channels: set[str] = set()
        if self.recorder is not None:
            channels |= self.recorder.channels
        if self.run_recording is not None:
            channels |= self.run_recording.recorder.channels
        self._recorded = frozenset(channels)

    def record(self, topic: Channel, message: Message) -> None:
        """Record ``message`` (a dict, its JSON encoded, or one :class:`Shared` by several
        recordings) on the agent's recordings."""
        recorder = self.recorder  # read once: close() may clear it on another thread
        if recorder is not None:
            recorder.record(topic, message)
        run = self.run_recording
        if run is not None:
            run.record(topic, message)

    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> None:
        """Declare everything; refuse (NameTaken) if the name is already in the federation.
        The platform starts held until its run starts (``waiting``)."""
        self.safety.enforce()  # held (waiting) until its run starts
        s = self.session
        callback = zenoh.handlers.Callback
        fed = self.config.federation
        self._refuse_taken_name()
        self._declared.append(
            s.declare_queryable(
                self.key(self.me, "sync"), callback(self._on_sync_query, indirect=False)
            )
        )
        # Best effort: a router with a UDP link beside its TCP one (deploy/routers) sends
        # pose there, so a pose never waits behind a lost TCP segment; the next pose
        # supersedes a lost one. Sync, control and status stay reliable.
        self._pose_pub = s.declare_publisher(
            self.key(self.me, "pose"), express=True, reliability=zenoh.Reliability.BEST_EFFORT
        )
        self._status_pub = s.declare_publisher(self.key(self.me, "status"))
        self._declared += [self._pose_pub, self._status_pub]
        self._pose_pub_id = self._pose_pub.id  # read once: each read builds a new object
        watched = keys.all_of(fed, "pose") if self.config.watch_all else None
        if watched is None and self.follow is not None:
            watched = self.key(self.follow, "pose")
        if watched is not None and not self._join_feed(watched):
            self._declared.append(
                self.fanout.subscribe(watched, self._on_pose)
                if self.fanout is not None
                else s.declare_subscriber(watched, callback(self._on_pose_sample, indirect=False))
            )
        self._declared.append(
            s.declare_subscriber(keys.control_key(fed), callback(self._on_control, indirect=False))
        )
        self._declared.append(
            s.liveliness().declare_subscriber(
                keys.all_agents(fed), callback(self._on_liveliness, indirect=False), history=True
            )
        )
        if self.config.runs_dir is not None:
            software_versions()  # now, not on Zenoh's thread when a run arms (git: up to 2 s)
            self.recording_server = RecordingServer(
                s, fed, self.me, self.config.runs_dir, busy=self._busy_recording,
                min_free_mb=self.config.record_min_free_mb,
            )  # fmt: skip
        self._declared.append(s.liveliness().declare_token(self.key(self.me)))
        started = time.monotonic()
        self._name_checks = [started + after for after in NAME_CHECKS_AFTER]
        if self.config.status_json is not None:
            path = Path(self.config.status_json)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._status_file = path.open("a", encoding="utf-8")
        log.info("agent %s (%s) up in federation %s", self.me, self.config.role, fed)

    def _refuse_taken_name(self) -> None:
        """Two agents may not share a name: ask liveliness whether ours is alive."""
        if name_alive(self.session, self.key(self.me)):
            raise NameTaken(
                f"agent {self.me} is already in federation {self.config.federation}: "
                "stop it first or choose another --name"
            )

    def _check_name_again(self, host: float) -> None:
        """At each of ``NAME_CHECKS_AFTER`` after start (host monotonic ``host``; called at
        every control step): ask who answers this agent's own sync key
        (:func:`~federation.runtime.names.look_for_others`). Two processes that started
        under one name at once both passed :meth:`_refuse_taken_name`; each now hears
        the other's session besides its own, and each holds for good
        (:meth:`_hold_for_name`): which one is genuine cannot be told in-band. The
        replies come on Zenoh's threads; a query that cannot be sent is tried again a
        period later."""

        def clash(sessions: list[str]) -> None:
            self.name_clash = clash_message(str(self.me), self.config.federation, sessions)

        key = self.key(self.me, "sync")
        look_again(self._name_checks, host, self.session, key, self.clock.now, clash)

    def _busy_recording(self) -> str | None:
        """Why recordings are not served now: a run started by ctl armed, running or
        frozen (its poses and sync replies go first on this agent's links)."""
        state = self.run_state
        if state.run_id is None or state.mode not in _ACTIVE:
            return None  # an agent on its own runs from reference time 0 for good
        return f"run {state.run_id} {state.mode}"

    def _hold_for_name(self, t_exec: float, host: float) -> None:
        """Safe hold for good: another process runs under this agent's name."""
        self.safety.apply(Trigger.NAME_TAKEN)
        self.count("name_taken_holds")
        log.error("%s: safe hold for good; stop one of them and restart the other", self.name_clash)
        self._event("name_taken_hold", t_exec, host, self.name_clash or "")

    def others(self) -> dict[str, tuple[float, wire.Pose]]:
        """Every other agent's latest pose, stamped on simulation (reference) time: the
        reference stamp it carries (its sender's estimate, no sync with the sender
        needed) or, for a sender that does not stamp, its own clock mapped through this
        agent's offset estimates (Eq. 5)."""
        out = {}
        t_exec = self.clock.now()
        for agent, sample in list(self.latest_poses.items()):
            if agent == self.me:  # watching every pose, its own comes back too
                continue
            stamped = self.latest_ref.get(agent)
            if stamped is not None and stamped[0] == sample.t:  # the sender's own stamp
                out[str(agent)] = (stamped[1], sample.pose)
                continue
            t_sim = self.timebase.peer_to_sim(agent, sample.t, t_exec)
            if t_sim is not None:
                out[str(agent)] = (t_sim, sample.pose)
        return out

    def close(self, wait: bool = True) -> None:
        """Undeclare everything (tokens and subscribers first); the caller closes the session.

        With ``wait`` a run's recording is finished (its manifest written) first, while
        the name is still this agent's: a process started under it at once would
        otherwise find the run unfinished and recover it beside the finish. Without
        (``fedlab host``, whose other agents fly on), it finishes on its own thread
        (:attr:`finishing`), which the caller joins."""
        self._closing = True  # no command but an abort is taken from here on
        self.safety.apply(Trigger.ENDED)  # leave the platform with every valve closed
        try:
            self.platform.close()  # a serial platform sends all-closed and releases its port
        except Exception as error:
            log.warning("closing the platform failed: %s", error)
        finishing = self._end_run_recording(wait=wait)
        if finishing is not None:
            self.finishing.append(finishing)
        undeclare_all(self._declared)
        for feed in self.links.leave_feeds(self):  # the last agent on it unsubscribes
            undeclare_all([feed.subscription] if feed.subscription is not None else [])
        emptied, orphaned = self.links.leave(self)
        undeclare_all([link.querier for link in emptied if link.querier is not None])
        for link in orphaned:  # the agents still on it look for a sender again
            for user in link.agents:
                user._next_sync_due = 0.0
        if self.recording_server is not None:
            self.recording_server.close()
            self.recording_server = None
        if self._status_file is not None:
            self._status_file.close()
            self._status_file = None
        if self.recorder is not None:
            try:
                self.recorder.close()
            finally:
                PROMISES.give_back(self.recorder.path.parent, self)
            self.recorder = None
            self._update_recorded()

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
    def reference_heading(
        self, t_exec: float, run_time: float | None, t_sim: float | None = None
    ) -> tuple[float, float]:
        """Guidance: the leader's maneuver on run time, or the followed heading
        (``t_sim``: simulation time at ``t_exec``, if known: the followed agent's clock
        when it is the reference, so not estimated twice in one step)."""
        if self.config.role == "leader":
            return (0.0, 0.0) if run_time is None else self.maneuver(run_time)
        if self.config.role == "member":
            return 0.0, 0.0  # its pose source decides where it goes
        received = self.latest_poses.get(self.follow) if self.follow else None
        # The followed agent's clock now: its samples are stamped on it.
        if self.follow is None:
            now = None
        elif self.follow is self.reference and t_sim is not None:
            now = t_sim
        else:
            now = self.timebase.peer_time(self.follow, t_exec)
        return track_heading(received, now, self.config.latency_compensation)

    def control_step(self) -> None:
        """Run state, link watch, guidance and one platform step (the platform's rate)."""
        if self.config.clock_step is not None:
            self._rehearse_clock_step()
        t_exec, host = self.clock.read()
        self._check_name_again(host)
        if host >= self._router_check:
            self._router_check = host + ROUTER_CHECK_PERIOD
            self._watch_router(host)
        t_sim = self.sim_time(t_exec)
        with self.safety.lock:  # the run's change and its triggers in one section
            with self._lock:
                events = self.run_state.update(t_sim)
                run_time = self.run_state.run_time(t_sim)
            self._tell_safety(events)
        if events:
            self._apply(events, t_exec, host)
        if self.name_clash is not None and not self.safety.holds(Hold.NAME_TAKEN):
            self._hold_for_name(t_exec, host)
        self._watch_link(t_exec, host)
        self._watch_fix_restart(host)
        restored = self.safety.enforce()  # a step never runs free while a hold stands
        if restored is not None:
            self.count("holds_restored")
            log.warning(
                "run %s: the platform was released; held again (%s)", self.run_state.mode, restored
            )
        self.guidance = self.reference_heading(t_exec, run_time, t_sim)
        if self.scenario is not None:
            if self._scenario_new_run:
                self._scenario_new_run = False
                self.scenario.new_run()
            self._scenario_reference(t_sim, run_time)
        self.guidance_at = (t_exec, host, t_sim, run_time)
        self.pose = self.platform.step(t_exec, *self.guidance, self.track)
        if self.scenario is not None and self.scenario.workspace_held and not self._left_area:
            self._left_area = True
            # The area's frame holds it already; the agent's supervisor says so too.
            self.safety.apply(Trigger.AREA_LEFT)
            log.warning("safe hold: %s", self.scenario.hold_reason)
            self._event("workspace_hold", t_exec, host, self.scenario.hold_reason or "")
        if self._status_now:
            self._status_now = False
            self.publish_status()

    def _scenario_reference(self, t_sim: float | None, run_time: float | None) -> None:
        """The scenario's 3-DOF reference from the others' poses on reference time."""
        assert self.scenario is not None
        frozen = self.run_state.mode == "frozen"
        ref = self.scenario.reference(t_sim, run_time, self.others(), self.pose, frozen)
        if ref is not None:
            self.guidance = (ref.heading, ref.rate)
            self.track = ref.track

    def _watch_link(self, t_exec: float, host: float) -> None:
        """Safe hold while the followed pose is stale; lifted once it flows again and a
        sync exchange has completed since (re-synchronized). Watched whatever else
        holds: the stale hold is one of its own, lifted by nothing but the link."""
        if self.follow is None:
            return
        if self._contest_hold(t_exec, host):
            return
        received = self.pose_received_at.get(self.follow)
        client = self._client_of(self.follow)
        last = None if client is None else client.last
        # On a shared feed the link is measured once for all its agents; the hold is each one's.
        threshold = None if self.feed is None else self.feed.watch.threshold
        action = self.link_watch.update(
            t_exec, received, None if last is None else last.t3, threshold
        )
        if action == "stale_hold" and received is not None:
            self.safety.apply(Trigger.LINK_STALE)
            self.count("stale_holds")
            log.warning(
                "no pose from %s for %.0f ms: safe hold", self.follow, (t_exec - received) * 1e3
            )
            self._event("stale_hold", t_exec, host, f"last pose {t_exec - received:.3f} s ago")
        elif action == "link_resumed":
            self.safety.apply(Trigger.LINK_RESUMED)
            log.info(
                "pose from %s flows again and sync resumed: %s",
                self.follow, _held_or_released(self.safety.hold),
            )  # fmt: skip
            self._event("link_resumed", t_exec, host, "")

    def _watch_router(self, host: float) -> None:
        """Hold (``no_router``) once the session has had no router for ``NO_ROUTER_HOLD``
        seconds after having one, and end a ctl run here: a leader or member flew on
        with no follower's stale watch to stop it, and no abort could reach it. Its
        router back, the hold is let go. A session that never had one (a peer) is left
        alone."""
        session = self.session
        if session is None:
            return
        if any(True for _ in session.info.routers_zid()):
            self._had_router, self._router_lost = True, None
            if self.safety.holds(Hold.NO_ROUTER):
                self.safety.apply(Trigger.ROUTER_BACK)
                log.warning("router back: %s", _held_or_released(self.safety.hold))
            return
        if not self._had_router:
            return
        if self._router_lost is None:
            self._router_lost = host
        if host - self._router_lost < NO_ROUTER_HOLD or self.safety.holds(Hold.NO_ROUTER):
            return
        detail = f"no router for {host - self._router_lost:.1f} s"
        self._end_run_here("router_lost", detail, host)
        self.safety.apply(Trigger.ROUTER_LOST)
        self.count("no_router_holds")
        log.error("%s: safe hold until it is back", detail)

    def _watch_fix_restart(self, host: float) -> None:
        """Hold (``fix_restart``) and end a ctl run here once the platform's estimate has
        restarted from agreeing outlier fixes: they are where the platform is only if the
        metrology is right (a frozen or glitching one repeats one wrong value). Let go
        only by ``fedlab ctl reset``, which acknowledges it."""
        chain = getattr(self.platform, "chain", None)
        # Its own flag, not its reason: held (waiting for a run), the chain's reason is
        # "held" whatever else it has seen.
        if not getattr(chain, "restarted", False) or self.safety.holds(Hold.FIX_RESTART):
            return
        detail = "the estimate restarted from agreeing outlier fixes: check the metrology"
        self._end_run_here("fix_restart", detail, host)
        self.safety.apply(Trigger.FIX_RESTARTED)
        self.count("fix_restart_holds")
        log.error("%s: safe hold until fedlab ctl reset", detail)

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
        if self._has_fix is not None and not self._has_fix():
            # Its prior is not a pose: a follower would steer by it, a formation pull
            # towards it (a restarted member's table origin moved another's track 0.27 m).
            self.count("pose_withheld_no_fix")
            return
        t_exec, host = self.clock.read()
        try:
            payload = wire.encode_pose(t_exec, self.pose)
        except ValueError:
            # Not a pose (NaN or infinity): never sent, and the platform that made it
            # held (the GNC chain's own guard holds first; this covers any platform).
            self.count("pose_not_finite")
            if not self.safety.holds(Hold.NONFINITE):
                self.safety.apply(Trigger.POSE_NONFINITE)  # for good: nothing lifts it
                log.error("own pose not finite (%s): not sent, platform held", self.pose)
            return
        self._pose_pub.put(
            payload, source_info=self._source_info(), attachment=self.reference_stamp(t_exec)
        )
        # Only the messages of recorded channels are built (issue 17: a lean agent).
        recorded = self._recorded
        if not recorded:
            return
        stamp = {"t_exec": t_exec, "host_monotonic": host}
        if Channel.POSE_SENT in recorded:
            self.record(Channel.POSE_SENT, stamp | self.pose._asdict())
        if Channel.REFERENCE in recorded:
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
                }
                | ({} if self.scenario is None else self.scenario.fields()),
            )
        truth = getattr(self.platform, "truth", None) if Channel.TRUTH in recorded else None
        if truth is not None:
            self.record(Channel.TRUTH, stamp | truth._asdict())

    def step(self) -> None:
        """One control step, then publish the pose."""
        self.control_step()
        self.publish_pose()

    def _apply(self, events: list[Event], t_exec: float, host: float) -> None:
        """Act on run-state events (the supervisor has heard them): a new recording and
        the scenario's new run when a start arms; log and record each; a run's
        recording finished when it ends."""
        for event in events:
            if event.kind == "armed":
                run = (self.run_state.run_id, self.run_state.start_at)
                if self.scenario is not None and run != self._scenario_run:
                    # Nothing of the last run's guidance carries over; begun on the loop's
                    # thread at its next step, not under a reference it is computing.
                    self._scenario_run = run
                    self._scenario_new_run = True
                self._begin_run_recording()
            level = logging.WARNING if event.kind in ("aborted", "ignored") else logging.INFO
            log.log(
                level, "run %s %s at reference time %s %s",
                self.run_state.run_id or "-", event.kind, event.t_sim, event.detail,
            )  # fmt: skip
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
            if event.kind in ("aborted", "done"):
                self._end_run_recording()

    # -- each run's recording ----------------------------------------------------------
    def _begin_run_recording(self) -> None:
        """A recording of the run just armed under runs_dir (unless --record records all)."""
        run_id = self.run_state.run_id
        if self.config.runs_dir is None or self.recorder is not None or run_id is None:
            return
        current = self.run_recording
        if current is not None and current.run_id == run_id:
            return  # re-armed: the same run
        self._end_run_recording()
        try:
            self.run_recording = RunRecording(
                self.config.runs_dir, run_id, str(self.me), self.config.record_channels,
                self.config.model_dump_json(), self.config.experiment,
                {"role": self.config.role, "follow": self.config.follow,
                 "latency_compensation": self.config.latency_compensation,
                 "reference": str(self.reference), "duration": self.run_state.duration},
                self.config.record_max_mb, self.config.record_min_free_mb,
            )  # fmt: skip
            self._update_recorded()
        except OSError as error:
            log.error("cannot record run %s under %s: %s", run_id, self.config.runs_dir, error)

    def _end_run_recording(self, wait: bool = False) -> threading.Thread | None:
        """Finish this run's recording (on a thread; ``wait``: joined); the thread."""
        run, self.run_recording = self.run_recording, None
        self._update_recorded()
        return None if run is None else run.finish(wait=wait)

    def due_for_sync(self, now: float) -> list[AgentId]:
        """The agents due for a sync request at host monotonic time ``now``, each
        scheduled for its next one: those in ``sync_with`` (or, when it is empty, the
        reference and the followed agent) every ``sync_period``; senders of poses
        without this agent's reference stamp, and with ``sync_all`` (or on the
        reference) every other agent alive, every ``sync_others_period`` on its own
        phase. Walks only those agents, and none before the earliest is due."""
        if now < self._next_sync_due:
            return []
        cfg = self.config
        targets = self._sync_targets()
        due = []
        earliest = math.inf
        for agent in targets:
            peer = self.peers.get(agent)
            link = None if peer is None or not peer.alive else peer.link
            if link is None:  # gone, or not attached yet (pairwise as of now)
                continue
            close = agent in self.close_sync
            if link.sender is not self:
                # Another agent on this clock queries it for all; taken over if it has
                # not for two periods (it left, or its loop ended before this one's).
                stalled = link.next_sync + 2 * (
                    cfg.sync_period if close else cfg.sync_others_period
                )
                if not self.links.claim(link, self, stalled <= now):
                    earliest = min(earliest, stalled)
                    continue
            if link.next_sync <= now:
                if close:
                    link.next_sync = now + 0.5 * cfg.sync_period  # due again at the next tick
                else:
                    link.next_sync = next_tick(link.next_sync, cfg.sync_others_period, now)
                due.append(agent)
            earliest = min(earliest, link.next_sync)
        self._next_sync_due = earliest
        return due

    def _sync_targets(self) -> list[AgentId] | set[AgentId]:
        """The agents this one queries: those in ``sync_with`` (or, when it is empty,
        the reference and the followed agent), senders of poses without its reference
        stamp, and with ``sync_all`` (or on the reference) every other agent seen, in
        the order seen."""
        if self.explicit_sync:
            return self.explicit_sync | self.pairwise
        if self.sync_all:
            return list(self.peers)  # liveliness may add one meanwhile
        return self.close_sync | self.pairwise

    def send_sync_requests(self, now: float | None = None) -> None:
        """Query every agent due at host monotonic ``now`` (default: the present), for
        every agent on the same link (each one's silence watch counts the request)."""
        for agent in self.due_for_sync(time.monotonic() if now is None else now):
            link = self.peers[agent].link
            assert link is not None  # due_for_sync gives only agents with a link
            try:
                if link.querier is None:
                    # One querier and one handler per link: a query costs a single call.
                    link.querier = self.session.declare_querier(
                        link.key,
                        consolidation=zenoh.ConsolidationMode.NONE,
                        timeout=self.config.sync_timeout,
                        express=True,
                    )
                    link.on_reply = zenoh.handlers.Callback(
                        functools.partial(_on_link_reply, link), indirect=False
                    )
                with link.lock:
                    payload = link.client.request(self.clock.now())
                link.querier.get(link.on_reply, payload=payload)
                host = time.monotonic()
                for user in link.agents:
                    user.silence.requested(agent, host)
            except Exception as error:  # session closing, or zenoh refusing the query
                log.warning("sync request to %s failed: %s", agent, error)

    # -- status ------------------------------------------------------------------------
    def status(self) -> Status:
        t_exec, host = self.clock.read()
        peers = {}
        # Only the agents it queries can have figures: not a walk of every agent seen
        # (a follower among 256 agents queries one or two of them).
        targets = self._sync_targets()
        with self._lock:
            for agent in targets if isinstance(targets, list) else sorted(targets, key=str):
                peer = self.peers.get(agent)
                link = None if peer is None else peer.link  # attached under this lock
                if peer is not None and link is not None and link.client.sent:
                    with link.lock:  # a reply may be changing it on another thread
                        view = peers[str(agent)] = peer_status(
                            link.client, t_exec, peer.alive, sharing=link.sharing
                        )
                    view.silent = self.silence.silent_for(agent, host) if peer.alive else None
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
            run_id=self.run_state.run_id,
            duration=self.run_state.duration,
            ready=self.readiness(t_exec),
            commands=list(self.command_log),
            platform=self.config.platform,
            follow=None if self.follow is None else str(self.follow),
            hold=self.safety.hold,
            pose_age=pose_age,
            valves_confirmed=getattr(self.platform, "valves_confirmed", None),
            pose=list(self.pose),
            peers=peers,
            counters=self.counter_snapshot(),
            contested=self.contested(),
            workspace=None if self.scenario is None else self.scenario.workspace(),
            loop=self.loop_stats(),
        )

    def readiness(self, t_exec: float) -> Readiness:
        """What preflight checks: platform, recording, the reference clock's estimate."""
        detail = ""
        blocking = self.safety.blocking()  # a hold a run's start does not lift
        if blocking is not None:
            detail = f"held ({blocking})"
        elif getattr(self.platform, "valves_confirmed", True) is False:
            detail = "valve command not confirmed (a write to the device was cut off)"
        else:
            chain = getattr(self.platform, "chain", None)
            # Why it would be closed were it not held (held waiting for its run, the
            # chain's reason is "held"): a platform with no fix fails preflight.
            reason = getattr(chain, "cause", getattr(chain, "reason", None))
            acquiring = getattr(chain, "acquiring", None)
            rejected = getattr(chain, "last_rejection", None) or "off the table or outliers"
            detail = {
                "no_fix": "no metrology fix yet",
                "stale_fix": "metrology fix stale",
                "stale_imu": "IMU silent",
                "settling": "estimate settling (its velocity not yet known)",
                "nonfinite": "estimate or reference not finite",
                "fix_rejected": f"metrology fixes rejected ({rejected})",
                "fix_restart": "estimate restarted from outlier fixes: ctl reset",
                "device_restart": "device restarted, not yet confirmed",
            }.get(reason or "", "")
            if acquiring is not None and reason in ("no_fix", "stale_fix"):
                detail = f"metrology fixes being acquired ({acquiring[0]} of {acquiring[1]} agree)"
        locked, bound = True, 0.0 if self.reference == self.me else None
        if self.reference != self.me:
            peer = self.peers.get(self.reference)
            with self._lock:
                client = None if peer is None else peer.client
                estimator = None if client is None else client.estimator
                locked = estimator is not None and estimator.locked
                bound = None if estimator is None else estimator.bound
        target = self.config.record if self.recorder is not None else self.config.runs_dir
        low = low_space(self.config) if self.recorder is None else None
        return Readiness(
            platform=not detail,
            platform_detail=detail,
            recording=target is not None and low is None,
            recording_to=low or (None if target is None else str(target)),
            reference_locked=locked,
            reference_bound=bound,
        )

    def loop_stats(self) -> dict[str, float]:
        """Control loop timing: rate and lateness of the recent ticks (ms)."""
        return loop_stats(self.platform.rate, self.lateness.values())

    def counter_snapshot(self) -> dict[str, int]:
        with self._count_lock:
            counters = dict(self.counters)
        if self.scenario is not None:  # workspace clamps and holds, relative sensing
            counters |= self.scenario.counters
        # The platform's own (a serial link's bad checksums, write timeouts, the device's
        # failsafe reports and restarts, the chain's closed steps): a real table's faults
        # had reached neither status nor the recording.
        platform = getattr(self.platform, "counters", None)
        if isinstance(platform, Mapping):
            counters |= platform
        run = self.run_recording
        if run is not None:  # what this run's recording left out (its budget, a full queue)
            report = run.recorder.report()
            counters["recording_dropped_over_budget"] = report["dropped_over_budget"]
            counters["recording_dropped_queue_full"] = report["dropped_queue_full"]
            counters["recording_write_errors"] = report["write_errors"]
        return counters

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

    def warn_silent_peers(self, status: Status) -> None:
        """Log once when a peer alive answers nothing (a link that carries liveliness but
        not queries), and once when it answers again."""
        for name, view in status.peers.items():
            if view.silent is not None and name not in self._silent_warned:
                self._silent_warned.add(name)
                self.count("silent_peer_alarms")
                log.warning("%s is alive but answered nothing for %.1f s", name, view.silent)
            elif view.silent is None and name in self._silent_warned:
                self._silent_warned.discard(name)
                log.info("%s answers again", name)

    def end(self) -> None:
        """Its duration has passed: every valve closed first (co-hosted agents may fly on
        for longer), then the last status (a put or a file write that waits no longer
        delays the hold)."""
        try:
            self.safety.apply(Trigger.ENDED)
        finally:
            self.publish_status()

    def publish_status(self) -> None:
        status = self.status()
        self.check_delay_margin(status)
        self.warn_silent_peers(status)
        line = status.model_dump_json()
        self._status_pub.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)
        if self._status_file is not None:
            try:
                self._status_file.write(line + "\n")
                self._status_file.flush()
            except (OSError, ValueError) as error:  # a full disk: the agent flies on
                self.count("status_write_errors")
                self.rejects("status line", f"{self.config.status_json}: {error}")
        run = self.run_recording
        if run is not None and not run.status_line(line):
            self.count("status_write_errors")
        if self.recording(Channel.STATUS):
            self.record(Channel.STATUS, line.encode())  # the line published: encoded once

    # -- Zenoh callbacks: quick, and never raise ---------------------------------------
    def _on_sync_query(self, query: zenoh.Query) -> None:
        clock = self.clock
        t2 = clock.now()  # read on arrival: the paper's t2
        try:
            payload = query.payload
            if payload is not None and self._oversized(len(payload), "sync_requests_oversized"):
                return
            request = b"" if payload is None else payload.to_bytes()
            try:
                # The send time rides in the attachment: the payload stays the paper's 64 bytes.
                served = serve(request, t2, self.pose, clock.now())
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

    def _on_sync_reply(self, link: SyncLink, reply: zenoh.Reply) -> None:
        """A reply on ``link``, for every agent on it (this one first): each admits it
        (one that finds the replier contested drops it, and resets the estimate they
        share, so every one of them holds), the client takes it once, and each counts,
        logs and records what came of it."""
        t3, host = self.clock.read()  # read on arrival: the paper's t3
        users = link.agents or (self,)
        try:
            ok = reply.ok  # each read of it builds a new sample: read once
            if ok is None:
                for user in users:
                    user.count("sync_reply_errors")
                return
            payload = ok.payload
            replier = reply.replier_id  # a new object at each read: read once for all
            source = None if replier is None else str(replier.zid)
            size = len(payload)
            # Each agent judges it by its own contest watch, except that the followers on
            # one pose feed judge their followed agent once, by the feed's (every one of
            # them looks: no short cut).
            admitted = True
            judged: list[PoseFeed] = []
            for user in users:
                feed = user.feed
                if feed is None or feed.agent != link.agent:
                    admitted &= user._admit_reply(link, source, size, host, None)
                elif all(feed is not seen for seen in judged):
                    judged.append(feed)
                    admitted &= user._admit_reply(link, source, size, host, feed)
            if not admitted:
                return
            for user in users:
                user.silence.answered(link.agent)
            t2s = None
            attachment = ok.attachment if self.config.four_timestamps else None
            if attachment is not None:
                try:
                    t2s = read_send_time(attachment.to_bytes())
                except wire.DecodeError:
                    self.count("sync_attachment_malformed")
            recorders = [user for user in users if user.recording(Channel.SYNC_EXCHANGE)]
            client = link.client
            with link.lock:
                steps = client.steps
                accepted = client.receive(payload.to_bytes(), t3, t2s)
                reason = client.last_rejection
                exchange = client.last
                estimate = client.offset_at(t3) if recorders else None
                stepped = client.steps > steps
            if stepped:
                jump = client.last_step or 0.0
                log.warning(
                    "clock step of %+.3f s between %s and %s: estimate reset",
                    jump,
                    ", ".join(str(user.me) for user in users),
                    link.agent,
                )
                for user in users:
                    user.count("clock_steps")
                    user._event("clock_step", t3, host, f"{link.agent}: {jump:+.6f} s")
                    user._clock_stepped_at(link.agent, jump, host)
            if accepted is None or exchange is None:
                self.rejects(f"sync reply ({reason})", f"from {link.key}")
                return
            if not recorders:
                return
            message = Shared({  # encoded once for every agent on the link
                "peer": str(link.agent),
                "t1": exchange.t1,
                "t2": exchange.t2,
                "t3": exchange.t3,
                "t2s": exchange.t2s,
                "offset": exchange.offset,
                "delay": exchange.delay,
                "estimate": estimate,
                "host_monotonic": host,
            })  # fmt: skip
            for user in recorders:
                user.record(Channel.SYNC_EXCHANGE, message)
        except Exception:
            log.exception("sync reply from %s failed", link.key)

    def _on_pose_sample(self, sample: zenoh.Sample) -> None:
        """A pose sample from this agent's own subscriber (no :class:`Fanout`)."""
        try:
            received = Received(sample)
        except Exception:
            log.exception("pose sample on %s unreadable", sample.key_expr)
            return
        self._on_pose(received)

    def _on_pose(self, sample: Received) -> None:
        # Arrival in the process, read once for all co-hosted agents (Fanout).
        host = sample.arrived if self.clock.source is time.monotonic else self.clock.source()
        t_recv = self.clock.at(host)
        try:
            parsed = self._pose_key(sample.key)
            if not self._admit_pose(sample, parsed, host):
                return
            read = self._read_pose(sample, (self,))
            if read is None:
                return
            decoded, stamp = read
            self.count("pose_received")
            if (
                parsed is not None
                and parsed[0] == self.follow
                and self._stale_on_arrival(decoded.t, t_recv, self.link_watch)
            ):
                self.count("pose_stale_dropped")  # never reaches the controller
                return
            if parsed is not None:
                agent = parsed[0]
                with self._pose_lock:  # judged and stored at once: no older one over it
                    fresh = in_order(self._pose_order, agent, sample.source(), decoded.t)
                    if fresh:
                        self.latest_poses[agent] = decoded
                        self.pose_received_at[agent] = t_recv
                if not fresh:
                    self.count("pose_out_of_order")
                    return
                self._place(agent, decoded.t, stamp)
            if not self.recording(Channel.POSE_RECEIVED):
                return
            message = {
                "agent": str(parsed[0]) if parsed else sample.key,
                "t": decoded.t,
                "t_recv": t_recv,
                "host_monotonic": host,
                **decoded.pose._asdict(),
            }
            # Shared: a run's recording and the agent's encode it once between them.
            self.record(Channel.POSE_RECEIVED, Shared(message))
        except Exception:
            log.exception("pose sample on %s failed", sample.key)

    def _stale_on_arrival(self, sent: float, t_recv: float, watch: LinkWatch) -> bool:
        """Whether a followed pose (stamped ``sent`` on its sender's clock, arrived at own
        ``t_recv``) is too old to steer by (a burst queued through a cut); a fresh one
        measures the link on ``watch`` for the stale threshold
        (:mod:`federation.core.linkwatch`)."""
        assert self.follow is not None
        client = self._client_of(self.follow)  # the time base's estimate, read directly
        if client is not None:
            offset = client.estimator.offset_at(t_recv)  # the sender's clock: t_recv + offset
            if offset is not None and watch.too_old(t_recv + offset - sent, client.delay):
                return True
        watch.observe(t_recv, sent)
        return False

    def _join_feed(self, key: str) -> bool:
        """Follow through the pose feed shared with the agents of this session that follow
        the same agent on the same sync link, judge its poses alike and record them
        (:mod:`federation.runtime.links`); False (the agent subscribes itself) without a
        :class:`Fanout`, or for an agent that watches every pose, has a scenario (it reads
        every peer's pose) or rehearses a clock step."""
        cfg, follow, fanout = self.config, self.follow, self.fanout
        if (
            fanout is None or follow is None or cfg.watch_all or self.scenario is not None
            or cfg.clock_step is not None
        ):  # fmt: skip
            return False
        # What makes two agents' judgement of a pose the same: the session's shared
        # subscriptions, the clock, the link whose estimate dates the pose (the key
        # _link_for shares it by: the followed agent is always queried), the threshold's
        # floor and the reference whose stamps are read. Who may speak for the followed
        # agent, on pose and sync alike, is recorded on the feed (_admit_reply).
        share = (
            "pose", fanout, self.clock, follow, cfg.federation, cfg.sync_period, cfg.estimator,
            cfg.sync_window, cfg.sync_timeout, cfg.four_timestamps, cfg.stale_after, self.ref_id,
        )  # fmt: skip
        feed = self.links.feed(self, share, lambda: PoseFeed(follow, LinkWatch(cfg.stale_after)))
        with feed.lock:
            if feed.subscription is None:
                feed.subscription = fanout.subscribe(key, functools.partial(_on_feed_pose, feed))
            # The session its agents heard for the followed agent before this one joined:
            # news of a new one reaches only the agents on the feed when it changes.
            speaker = feed.contest.speaker(str(follow))
        if speaker is not None and follow == self.reference:
            with self._lock:
                self._reference_zid = self._reference_zid or speaker
        self.feed = feed
        return True

    def _on_feed_pose(self, feed: PoseFeed, sample: Received) -> None:
        """A pose of the followed agent on ``feed``, for every agent on it (this one
        first): admitted once (its size, its source, its age on arrival by the estimate
        they share), the link measured once; each agent stores, counts and records it."""
        users = feed.agents or (self,)
        host = sample.arrived if self.clock.source is time.monotonic else self.clock.source()
        t_recv = self.clock.at(host)
        agent = feed.agent
        try:
            if sample.size > MAX_SMALL_PAYLOAD:
                _count_all(users, "pose_oversized")
                return
            if not self._contest_verdict(agent, "pose", sample.source(), host, feed):
                return
            read = self._read_pose(sample, users)
            if read is None:
                return
            decoded, stamp = read
            # Dated by the estimate of the link they share: read through the first of
            # them that has seen the agent (liveliness may reach one before another).
            judge = (
                self if agent in self.peers else next((u for u in users if agent in u.peers), self)
            )
            if judge._stale_on_arrival(decoded.t, t_recv, feed.watch):
                _count_all(users, "pose_received")
                _count_all(users, "pose_stale_dropped")  # never reaches a controller
                return
            with feed.lock:  # judged and stored at once: no older one over it
                fresh = in_order(feed.order, agent, sample.source(), decoded.t)
                if fresh:
                    for user in users:
                        user.latest_poses[agent] = decoded
                        user.pose_received_at[agent] = t_recv
            if not fresh:
                _count_all(users, "pose_received")
                _count_all(users, "pose_out_of_order")  # never overwrites a newer one
                return
        except Exception:
            log.exception("pose sample on %s failed", sample.key)
            return
        message: Shared | None = None
        for user in users:  # one agent's failure must not keep the pose from the rest
            try:
                user.count("pose_received")
                user._place(agent, decoded.t, stamp)
                if user.recording(Channel.POSE_RECEIVED):
                    if message is None:  # built and encoded once, queued by each recorder
                        message = Shared({
                            "agent": str(agent), "t": decoded.t, "t_recv": t_recv,
                            "host_monotonic": host, **decoded.pose._asdict(),
                        })  # fmt: skip
                    user.record(Channel.POSE_RECEIVED, message)
            except Exception:
                log.exception("pose sample on %s failed for %s", sample.key, user.me)

    def _on_control(self, sample: zenoh.Sample) -> None:
        t_exec, host = self.clock.read()
        try:
            command = self._read_command(sample)
            if command is None:
                return
            self.count("control_received")
            if command.command == "abort":
                # First, before anything is judged or said: every valve closed and the run
                # aborted, under the safety lock, so no release judged on the loop's thread
                # before the abort can follow its hold.
                events = self._run_command(command, t_exec)
                verdict = self.gate.admit(command.command, command.issuer, command.seq)
                if not self._admitted(command, verdict):
                    return
            else:
                verdict = self.gate.admit(command.command, command.issuer, command.seq)
                if not self._admitted(command, verdict):
                    return
                refused = self._not_mine(command) or self._recorded_before(command)
                if refused is not None:  # refused before the run state sees it
                    events = [Event("ignored", self.sim_time(t_exec), refused)]
                else:
                    events = self._run_command(command, t_exec)
            ignored = [e.detail for e in events if e.kind == "ignored"]
            if ignored:
                self.count("commands_ignored")
            self._command_outcome(command, "ignored" if ignored else "applied", "; ".join(ignored))
            self._record_command(command, t_exec, host)
            self._apply(events, t_exec, host)
            self._status_now = True  # ctl waits for it: at the next step, not in a second
        except Exception:
            log.exception("control sample on %s failed", sample.key_expr)

    def _read_command(self, sample: zenoh.Sample) -> Command | None:
        """The command in ``sample``; None (counted, logged, reported to ctl where it
        names itself) if it does not validate, except an abort, honoured however
        malformed the rest of it is."""
        payload = sample.payload.to_bytes()
        try:
            return Command.model_validate_json(payload)
        except ValidationError as error:
            self.count("control_malformed")
            why = validation_reason(error)
            self.rejects("control command", f"{sample.key_expr}: {why}")
            if is_abort(payload):
                return Command(command="abort", seq=-1, issuer="malformed")
            reported = malformed_outcome(payload, why)
            if reported is not None:  # ctl says why, not "command not seen"
                self.command_log.append(reported)
            return None

    def _admitted(self, command: Command, verdict: Verdict) -> bool:
        """Whether the gate let ``command`` through; a drop counted, logged and reported
        (a repeat only counted: ctl publishes each command 3 times)."""
        if verdict.admitted:
            return True
        if verdict.outcome == "repeat":
            self.count("commands_repeated")
            return False
        self.count("commands_dropped")
        self._command_outcome(command, verdict.outcome, verdict.detail)
        log.warning(
            "dropped %s from %s: %s (%s)",
            command.command, command.issuer, verdict.outcome, verdict.detail,
        )  # fmt: skip
        return False

    def _run_command(self, command: Command, t_exec: float) -> list[Event]:
        """Apply ``command`` to the run state and tell the supervisor what came of it, in
        one section under the safety lock: no hold or release is decided between the
        run's change and its trigger. An abort closes every valve first; a reset
        applied (not ignored) is the operator's, whatever the run's mode."""
        with self.safety.lock:
            if command.command == "abort":
                self.safety.close_valves()
            with self._lock:
                events = self.run_state.command(command, self.sim_time(t_exec))
                if command.maneuver is not None and any(e.kind == "armed" for e in events):
                    self.maneuver = _maneuver(command.maneuver)
            self._tell_safety(events)
            if command.command == "reset" and not any(e.kind == "ignored" for e in events):
                self._acknowledge_restart()
                self.safety.apply_locked(Trigger.OPERATOR_RESET)
        return events

    def _tell_safety(self, events: Iterable[Event]) -> None:
        """The triggers of run-state ``events``, the safety lock held by the caller."""
        for event in events:
            trigger = _RUN_TRIGGERS.get(event.kind)
            if trigger is not None:
                self.safety.apply_locked(trigger)

    def _record_command(self, command: Command, t_exec: float, host: float) -> None:
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

    def _not_mine(self, command: Command) -> str | None:
        """Why a command is not for this agent: it is closing (its recording finishing, a
        start had armed a run no one would finish and released the platform), or the
        command names the participants and not this one (a start for one experiment had
        armed, and later released, every agent waiting in the federation, none of them
        preflighted or awaited by ctl)."""
        if self._closing:
            return "this agent is stopping"
        return command.not_for(str(self.me))

    def _recorded_before(self, command: Command) -> str | None:
        """Why a start must be refused: its run is recorded on this host already (a run
        id used again had truncated the finished recording its manifest still listed)."""
        runs_dir, run_id = self.config.runs_dir, command.run_id
        if command.command != "start" or runs_dir is None or run_id is None:
            return None
        current = self.run_recording
        if current is not None and current.run_id == run_id:
            return None  # this run, armed again
        folder = Path(runs_dir) / run_id
        stem = f"{self.me.lab}-{self.me.name}"
        recorded = (f"{stem}.mcap", f"{stem}.mcap.partial", manifest_name(stem))
        if any((folder / name).exists() for name in recorded):  # .partial: being recovered
            return f"run {run_id} is recorded here already ({folder}): start another run id"
        return None

    def _command_outcome(self, command: Command, outcome: str, detail: str) -> None:
        """Remember what became of a command: status reports the last few, so ctl can
        say why an agent did not confirm."""
        self.command_log.append(
            CommandOutcome(
                command=command.command, issuer=command.issuer[:200], seq=command.seq,
                outcome=outcome, detail=detail,
            )
        )  # fmt: skip

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
            if peer is not None and peer.alive != alive:
                with self._contest_lock:  # a restarted agent has a new session id
                    self.contest.forget(str(agent))
                with self._pose_lock:
                    self._pose_order.pop(agent, None)  # and may count time afresh
                feed = self.feed
                if feed is not None and feed.agent == agent:
                    with feed.lock:
                        feed.contest.forget(str(agent))
                        feed.order.pop(agent, None)
            if peer is None:
                if not alive:
                    return
                peer = self.peers[agent] = Peer(agent, index=len(self.peers))
                if self._queries(agent):
                    self._attach(peer)
            elif alive and not peer.alive:
                self.silence.forget(agent)
                link = peer.link
                if link is not None:
                    link.reset()  # a restarted agent has a new clock
                    link.next_sync = self._first_sync(peer)
            peer.alive = alive
            self._next_sync_due = 0.0  # due_for_sync looks again
        log.info("agent %s %s", agent, "joined" if alive else "left")

    # -- one reference time: the pose's reference stamp (issue 17) ---------------------
    def _pose_key(self, key: str) -> tuple[AgentId, str | None] | None:
        """``keys.parse_agent_key`` of a pose key, remembered: every sample of a sender
        has the same key, and parsing validates (and allocates) an AgentId each time."""
        cache = self._pose_keys
        if key not in cache:
            if len(cache) >= 4096:  # a flood of made-up keys: start over, stay bounded
                cache.clear()
            cache[key] = keys.parse_agent_key(self.config.federation, key)
        return cache[key]

    def reference_stamp(self, t_exec: float) -> bytes:
        """The attachment of a pose stamped ``t_exec`` (wire.encode_stamp): its reference
        time and error bound (this agent's one-way delay to the reference)."""
        if self.reference == self.me:
            return wire.encode_stamp(self.ref_id, t_exec, 0.0)
        client = self._client_of(self.reference)
        offset = None if client is None else client.offset_at(t_exec)
        bound = None if client is None else client.delay
        if offset is None or bound is None:
            return wire.encode_stamp(self.ref_id, None, None)
        return wire.encode_stamp(self.ref_id, t_exec + offset, bound)

    def _read_pose(
        self, sample: Received, users: Iterable[AgentRuntime]
    ) -> tuple[wire.PoseSample, wire.RefStamp | None] | None:
        """A pose sample's pose and reference stamp (None without one, or on another
        reference: counted by each of ``users``); None if either is malformed, counted
        by each of ``users`` and logged once."""
        try:
            decoded = sample.pose()
        except wire.DecodeError as error:
            _count_all(users, "pose_malformed")
            self.rejects("pose sample", f"{sample.key}: {error}")
            return None
        try:
            stamp = sample.stamp()
        except wire.DecodeError as error:
            _count_all(users, "pose_stamp_malformed")
            self.rejects("pose stamp", f"{sample.key}: {error}")
            return None
        if stamp is not None and stamp.ref_id != self.ref_id:
            _count_all(users, "pose_other_reference")
            stamp = None
        return decoded, stamp

    def _place(self, agent: AgentId, t: float, stamp: wire.RefStamp | None) -> None:
        """Remember where a peer's pose stamped ``t`` sits on reference time; a sender
        that does not stamp on this agent's reference is synced with pairwise."""
        if stamp is None:
            self.latest_ref.pop(agent, None)
            if agent != self.me and agent not in self.pairwise:
                with self._lock:
                    self.pairwise.add(agent)
                    peer = self.peers.get(agent)  # not seen yet: linked when it is
                    if peer is not None and peer.link is None:
                        self._attach(peer)
                    self._next_sync_due = 0.0
                log.info("%s sends no reference stamp: synced pairwise", agent)
        elif stamp.t_ref is not None and stamp.bound is not None:
            self.latest_ref[agent] = (t, stamp.t_ref, stamp.bound)
        else:  # a stamping sender not yet synchronized: not placed until it is
            self.latest_ref.pop(agent, None)

    # -- trust: who speaks for a peer (issue 13, federation.core.contest) -------------
    def _source_info(self) -> zenoh.SourceInfo:
        """This session's id on each pose sample: a follower tells two sources apart."""
        self._pose_sn += 1
        return zenoh.SourceInfo(self._pose_pub_id, self._pose_sn)

    def _oversized(self, size: int, counter: str) -> bool:
        """Drop (and count) a payload of ``size`` bytes far larger than any pose or sync
        message, before it is copied or decoded."""
        if size <= MAX_SMALL_PAYLOAD:
            return False
        self.count(counter)
        return True

    def _admit_pose(
        self, sample: Received, parsed: tuple[AgentId, str | None] | None, host: float
    ) -> bool:
        """Whether a pose sample may be used: not oversized, and its peer not contested
        (its source: the publisher's session id in the source info, None without one)."""
        if self._oversized(sample.size, "pose_oversized"):
            return False
        if parsed is None:
            return True
        return self._contest_verdict(parsed[0], "pose", sample.source(), host)

    def _admit_reply(
        self, link: SyncLink, source: str | None, size: int, host: float, feed: PoseFeed | None
    ) -> bool:
        """Whether a sync reply (its payload ``size`` bytes) may be used: not oversized,
        and the peer not contested (its ``source``: the replier's session id, which
        Zenoh sets on every reply); judged for this agent, or for every agent on
        ``feed``, whose record of the agent they follow covers its poses and its
        replies alike (a contest on one drops what comes on the other too)."""
        if size > MAX_SMALL_PAYLOAD:
            _count_all(
                (self,) if feed is None else (feed.agents or (self,)), "sync_replies_oversized"
            )
            return False
        return self._contest_verdict(link.agent, "sync", source, host, feed)

    def _contest_verdict(
        self,
        agent: AgentId,
        channel: ContestChannel,
        source: str | None,
        host: float,
        feed: PoseFeed | None = None,
    ) -> bool:
        """Whether ``source`` may speak for ``agent`` on ``channel``: judged by this
        agent's contest watch, or by ``feed``'s (the record of the agent its agents
        follow) for every agent on it."""
        name = str(agent)
        watch, lock = (
            (self.contest, self._contest_lock) if feed is None else (feed.contest, feed.lock)
        )
        users = (self,) if feed is None else (feed.agents or (self,))
        with lock:
            outcome = watch.observe(name, channel, source, host)
            reason = watch.reason(name, host) if outcome == "contested" else None
            spoke = outcome == "ok" and watch.new_speaker(name, source)
        if outcome == "ok":
            if spoke:  # first heard, or a new session for it
                for user in users:
                    if user.reference == agent:
                        user._reference_session(source, host)
            return True
        _count_all(users, "contested_dropped")
        if outcome == "contested":
            for user in users:
                user.count("contested")
                user.latest_poses.pop(agent, None)  # what it sent so far is suspect too
                peer = user.peers.get(agent)
                link = None if peer is None else peer.link
                if link is not None:
                    link.reset()  # the estimate of every agent on the link: all hold
            log.error("%s is contested: %s; nothing from it is used", agent, reason)
        return False

    def _reference_session(self, source: str | None, host: float) -> None:
        """The session speaking for the reference is ``source`` (first heard, or new). A
        new one during a run started by ctl is the reference restarted: its new process
        waits, flies no maneuver and may count time afresh, so the run is over here
        (:meth:`_end_run_here`, ``reference_restarted``). A link cut longer than the
        lease is not: the same session comes back."""
        with self._lock:  # Zenoh's threads for poses and for sync replies both call it
            before, self._reference_zid = self._reference_zid, source
        if before is not None and before != source:
            detail = f"{self.reference} restarted (session {before[:8]} now {source!s:.8})"
            self._end_run_here("reference_restarted", detail, host)

    def _clock_stepped_at(self, agent: AgentId, jump: float, host: float) -> None:
        """``agent``'s clock stepped by ``jump`` s (or this agent's own did): its poses
        count time afresh, so their order is forgotten (a step back had its every pose
        dropped as out of order until its clock passed the old one); the reference's
        ends a ctl run here (run time would jump by it)."""
        with self._pose_lock:
            self._pose_order.pop(agent, None)
        feed = self.feed
        if feed is not None and feed.agent == agent:
            with feed.lock:
                feed.order.pop(agent, None)
        if agent == self.reference:
            detail = f"{agent}'s clock stepped {jump:+.3f} s against this agent's"
            self._end_run_here("reference_clock_steps", detail, host)

    def _end_run_here(self, counter: str, detail: str, host: float) -> None:
        """Abort a run started by ctl (armed, running or frozen) on this agent alone: the
        reference it counts time on is no longer the one the run began with (restarted,
        or its clock stepped). Every valve closed, ``counter`` counted, ``detail`` in the
        log and the recording; nothing outside a ctl run."""
        t_exec = self.clock.at(host)
        state = self.run_state
        with self.safety.lock:  # before anything else is said or recorded: every valve closed
            with self._lock:
                if state.run_id is None or state.mode not in _ACTIVE:
                    return
                self.safety.close_valves()
                events = state.command(_LOCAL_ABORT, self.sim_time(t_exec))
            self._tell_safety(events)
        self.count(counter)
        log.error("run %s: %s: aborted here", state.run_id, detail)
        self._apply([dataclasses.replace(e, detail=detail) for e in events], t_exec, host)
        self._status_now = True

    def _contest_hold(self, t_exec: float, host: float) -> bool:
        """Safe hold while the followed agent is contested; once the contest clears,
        resume only when a pose and a sync exchange have arrived since (True: held)."""
        assert self.follow is not None and self._follow_name is not None
        with self._contest_lock:
            reason = self.contest.reason(self._follow_name, host)
        feed = self.feed
        if reason is None and feed is not None:  # its poses are judged on the feed
            with feed.lock:
                reason = feed.contest.reason(self._follow_name, host)
        if reason is not None:
            self._contest_cleared = None
            if not self.safety.holds(Hold.CONTESTED):
                self.safety.apply(Trigger.CONTESTED)
                self.count("contested_holds")
                log.error("followed agent %s contested (%s): safe hold", self.follow, reason)
                self._event("contested_hold", t_exec, host, reason)
            return True
        if not self.safety.holds(Hold.CONTESTED):
            return False
        if self._contest_cleared is None:
            self._contest_cleared = t_exec
        received = self.pose_received_at.get(self.follow)
        client = self._client_of(self.follow)
        last = None if client is None else client.last
        cleared = self._contest_cleared
        if received is None or received <= cleared or last is None or last.t3 <= cleared:
            return True
        self.safety.apply(Trigger.CONTEST_CLEARED)
        log.warning(
            "contest of %s cleared, pose and sync since: %s",
            self.follow, _held_or_released(self.safety.hold),
        )  # fmt: skip
        self._event("contest_cleared", t_exec, host, "")
        return False

    def _acknowledge_restart(self) -> None:
        """An operator's reset acknowledges an estimate restarted from outlier fixes."""
        acknowledge = getattr(getattr(self.platform, "chain", None), "acknowledge_restart", None)
        if acknowledge is not None:
            acknowledge()

    @property
    def hold(self) -> Hold | None:
        """Why every valve is held closed (None: they may open): the supervisor's."""
        return self.safety.hold

    def contested(self) -> dict[str, str]:
        """Every contested peer and why (status)."""
        host = self.clock.read()[1]
        with self._contest_lock:
            contested = self.contest.contested(host)
        feed = self.feed
        if feed is not None:  # the followed agent's poses are judged on the feed
            with feed.lock:
                contested = feed.contest.contested(host) | contested
        return contested

    def _first_sync(self, peer: Peer) -> float:
        """When ``peer`` gets its first request (again, after a restart): at once for the
        ones synced every period, else spread over ``sync_others_period`` by the order
        it was seen (golden-ratio phases, so no tick carries a burst however many agents
        join or come back together)."""
        if peer.agent in self.close_sync:
            return 0.0
        phase = (peer.index * 0.6180339887498949) % 1.0
        return time.monotonic() + phase * self.config.sync_others_period

    def _client_of(self, agent: AgentId) -> SyncClient | None:
        """The sync client of ``agent``'s link (None: not seen, or not queried)."""
        peer = self.peers.get(agent)
        return None if peer is None else peer.client

    def _queries(self, agent: AgentId) -> bool:
        """Whether this agent queries ``agent`` (one of :meth:`_sync_targets`)."""
        if agent in self.pairwise:
            return True
        if self.explicit_sync:
            return agent in self.explicit_sync
        return self.sync_all or agent in self.close_sync

    def _attach(self, peer: Peer) -> None:
        """Give ``peer`` its sync link (under ``_lock``): this agent queries it now."""
        link = self._link_for(peer.agent)
        if link.sharing == 1:  # a new link: this agent schedules its first request
            # Its own phase, from when it was seen: senders that turn pairwise together
            # are not all queried on one tick.
            link.next_sync = self._first_sync(peer)
        peer.attach(link)

    def _link_for(self, agent: AgentId) -> SyncLink:
        """The sync link to ``agent``, which this agent queries: shared with the agents
        of this session that read the same clock object and query ``agent`` alike
        (:mod:`federation.runtime.links`); its own for an agent it queries pairwise
        (its poses carry no stamp on this agent's reference) or on a clock that a
        rehearsal steps."""
        cfg = self.config
        close = agent in self.close_sync
        queried = close or (self.sync_all and not self.explicit_sync)
        share: tuple[Any, ...] = (self, agent)
        if queried and cfg.clock_step is None:
            period = cfg.sync_period if close else cfg.sync_others_period
            share = (
                self.clock, agent, cfg.federation, period, cfg.estimator, cfg.sync_window,
                cfg.sync_timeout, cfg.four_timestamps,
            )  # fmt: skip
        return self.links.join(
            self, share, lambda: SyncLink(agent, self.key(agent, "sync"), self._new_client())
        )

    def _new_client(self) -> SyncClient:
        cfg = self.config
        return SyncClient(make_estimator(cfg.estimator, cfg.sync_window), timeout=cfg.sync_timeout)


def _held_or_released(hold: Hold | None) -> str:
    return "released" if hold is None else f"held ({hold})"


def _on_feed_pose(feed: PoseFeed, sample: Received) -> None:
    """A pose on ``feed``: handled once, by the first agent still on it, for all."""
    users = feed.agents
    if users:
        users[0]._on_feed_pose(feed, sample)


def _count_all(users: Iterable[AgentRuntime], name: str) -> None:
    for user in users:
        user.count(name)


def _on_link_reply(link: SyncLink, reply: zenoh.Reply) -> None:
    """A sync reply on ``link``: handled once, by the first agent still on it, for all."""
    users = link.agents
    if users:
        users[0]._on_sync_reply(link, reply)


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

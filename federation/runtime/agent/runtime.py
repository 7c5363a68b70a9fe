"""The agent: one platform on an open Zenoh session, its parts wired together.

Threads and who owns what:

- Zenoh's network thread runs the callbacks (``indirect=False``): the sync
  queryable reads ``t2`` and replies at once; a sync reply reads ``t3`` and is
  matched under its link's lock; pose, liveliness and control samples are decoded
  and stored. Callbacks never raise and never block: a bad payload is logged and
  counted.
- The agent's own loop (:func:`~federation.runtime.loop.run_together`) steps the
  platform, publishes pose and status and sends sync requests. Agents hosted in one
  process may share that thread.
- A recorder thread writes the MCAP file (:mod:`federation.runtime.recorder`).

:class:`AgentRuntime` is a thin facade over parts that each own one state:

- :class:`~federation.runtime.safety.Safety`: every hold, and the platform held or
  released as the supervisor decides (:mod:`federation.core.holds`);
- :class:`~federation.runtime.agent.commands.RunControl`: the run and the commands;
- :class:`~federation.runtime.agent.peers.PeerTable`: the peers, their sync links
  and the schedule of requests;
- :class:`~federation.runtime.agent.intake.PoseIntake`: the peers' poses, who may
  speak for each, the followed link's measure;
- :class:`~federation.runtime.agent.watches.Watches`: what is watched at every step
  (link, contest, router, estimate, name, area), named as triggers;
- :class:`~federation.runtime.agent.recordings.Recordings` and
  :class:`~federation.runtime.agent.reporting.Reporter`: what is recorded and said.

The decisions are made in the pure core: holds (:mod:`federation.core.holds`), run
modes (:mod:`federation.core.runstate`), time bases (:mod:`federation.core.timebase`),
the sync exchange's two halves (:mod:`federation.core.sync`), the stale-link hold
(:mod:`federation.core.linkwatch`).
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from agents.flown import FollowedModel
from agents.guidance import HeadingEstimator, Track
from agents.platform import Platform, make_platform
from agents.scenario import ScenarioGuidance, make_scenario
from federation.core import keys, wire
from federation.core.channels import Channel
from federation.core.counters import Count
from federation.core.holds import Hold, Trigger
from federation.core.keys import AgentId
from federation.core.linkwatch import LinkWatch
from federation.core.runstate import RunState
from federation.core.sync import serve
from federation.core.timebase import TimeBase
from federation.runtime.agent.commands import RunControl, maneuver_of
from federation.runtime.agent.intake import PoseIntake
from federation.runtime.agent.peers import Peer, PeerTable
from federation.runtime.agent.recordings import Recordings
from federation.runtime.agent.rejoining import Rejoining
from federation.runtime.agent.reporting import Reporter
from federation.runtime.agent.role import RoleKeeping
from federation.runtime.agent.twin import Twin
from federation.runtime.agent.watches import Watches
from federation.runtime.clock import ExecClock
from federation.runtime.collect import RecordingServer
from federation.runtime.fanout import Fanout
from federation.runtime.links import PoseFeed, SyncLink, SyncLinks
from federation.runtime.loop import run_together
from federation.runtime.names import NameTaken, name_alive
from federation.runtime.recorder import Message
from federation.runtime.routerwatch import watch_routers
from federation.runtime.runs import software_versions
from federation.runtime.safety import Safety
from federation.runtime.session import undeclare_all
from federation.runtime.syncglue import Served, serve_query
from schemas.config import AgentConfig
from schemas.messages import CommandOutcome, Readiness, Status
from schemas.platform import load_platform

__all__ = ["AgentRuntime"]

log = logging.getLogger("fedlab.agent")


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
        self._config = config
        self.session = session
        self.fanout = fanout  # shared pose subscriptions of agents on one session
        # Sync links: shared with the agents of this session on the same clock object.
        self.links = links if links is not None else SyncLinks()
        self.me = config.agent
        self.clock = clock or ExecClock(config.clock_offset, config.clock_drift_ppm)
        if platform is None and config.role == "stand-in":  # nothing to move until it claims
            platform = Twin(load_platform(config.platform), config.seed)
        self.platform: Platform = platform or make_platform(
            config.platform, config.seed, rate=config.pose_rate, preset=config.platform_preset
        )
        self.maneuver = maneuver or maneuver_of(config.maneuver)
        self.follow = AgentId.parse(config.follow) if config.follow else None
        # A formation, docking or adaptive-gain part (agents.scenario) gives the 3-DOF
        # reference; its platform takes and gives the common frame.
        self.scenario: ScenarioGuidance | None = None
        if config.scenario is not None:
            self.scenario = make_scenario(
                str(self.me), config.scenario, self.platform,
                None if self.follow is None else str(self.follow), config.latency_compensation,
            )  # fmt: skip
            self.platform = self.scenario.platform
        self.track: Track | None = None  # the last position reference, common frame
        if config.reference is not None:
            self.reference = AgentId.parse(config.reference)
        elif config.role == "follower" and self.follow is not None:
            self.reference = self.follow
        else:
            self.reference = self.me
        self.ref_id = wire.reference_id(str(self.reference))
        self.pose = wire.Pose()
        self.guidance = (0.0, 0.0)  # last heading and rate references
        self.heading_estimator = HeadingEstimator()  # a follower's, over the followed samples
        # Its input: the maneuver as the followed platform's preset flies it, if known.
        preset = config.follow_preset
        self.followed_model = FollowedModel(None if preset is None else load_platform(preset))
        # When they were computed: t_exec, host monotonic, t_sim, run time.
        self.guidance_at: tuple[float, float, float | None, float | None] = (0.0, 0.0, None, None)
        self.safety = Safety(self.platform)  # every hold and release
        self.peer_table = PeerTable(self)
        # Own clock <-> reference time <-> a peer's clock, through the peers' estimates.
        self.timebase = TimeBase(self.me, self.reference, self.peer_table.peers)
        self.recordings = Recordings(config, str(self.me))
        self.commands = RunControl(self, self.recordings)
        self.intake = PoseIntake(self, self.peer_table, self.commands)
        self.watches = Watches(self, self.intake, self.peer_table, self.commands)
        self.reporter = Reporter(self, self.intake, self.peer_table, self.commands, self.recordings)
        self.rejoining = Rejoining(self, self.commands)  # a run under way joined
        self.commands.admit = self.rejoining.admit
        self.reporter.rejoin_report = self.rejoining.report
        # The leader's role, in an experiment with a stand-in (federation.core.standin).
        self.role = RoleKeeping(self, self.peer_table, self.commands, self.rejoining)
        self.commands.handback = self.role.handback
        self.commands.handback_concerns = self.role.concerns
        self.reporter.role_report = self.role.report
        self.role.switched = self.heading_estimator.reset
        self.recording_server: RecordingServer | None = None
        self._clock_stepped = False
        self._blocking_shown: Hold | None = None  # the blocking hold of the last step
        self._pose_sn = 0  # sequence number in the pose samples' source info
        self._declared: list[Any] = []
        self._pose_pub: Any = None
        self._pose_pub_id: Any = None

    # -- the parts' state, read by callers and tests ---------------------------------
    @property
    def config(self) -> AgentConfig:
        return self._config

    @config.setter
    def config(self, config: AgentConfig) -> None:
        """A new config (its identity unchanged): the parts that read it see it too."""
        self._config = config
        self.recordings.config = config

    @property
    def run_state(self) -> RunState:
        return self.commands.run_state

    @property
    def command_log(self) -> deque[CommandOutcome]:
        return self.commands.log

    @property
    def peers(self) -> dict[AgentId, Peer]:
        return self.peer_table.peers

    @property
    def latest_poses(self) -> dict[AgentId, wire.PoseSample]:
        return self.intake.latest_poses

    @property
    def pose_received_at(self) -> dict[AgentId, float]:
        return self.intake.pose_received_at

    @property
    def link_watch(self) -> LinkWatch:
        return self.intake.link_watch

    @property
    def feed(self) -> PoseFeed | None:
        return self.intake.feed

    @property
    def counters(self) -> Counter[Count]:
        return self.reporter.counters

    @property
    def lateness(self) -> Any:
        return self.reporter.lateness

    @property
    def name_clash(self) -> str | None:
        return self.watches.name_clash

    @property
    def finishing(self) -> list[threading.Thread]:
        return self.recordings.finishing

    @property
    def hold(self) -> Hold | None:
        """Why every valve is held closed (None: they may open): the supervisor's."""
        return self.safety.hold

    # -- services the parts share ----------------------------------------------------
    def key(self, agent: AgentId, topic: str | None = None) -> str:
        return keys.agent_key(self.config.federation, agent, topic)

    def count(self, name: Count) -> None:
        """Bump a counter; callbacks may run on several Zenoh threads at once."""
        self.reporter.count(name)

    def reject(self, kind: str, message: str) -> None:
        """Log a rejected input, rate limited per kind."""
        self.reporter.rejects(kind, message)

    def recording(self, topic: Channel) -> bool:
        """Whether ``topic`` is recorded: callbacks build no message otherwise."""
        return self.recordings.recording(topic)

    def record(self, topic: Channel, message: Message) -> None:
        """Record ``message`` on the agent's recordings."""
        self.recordings.record(topic, message)

    def event(self, kind: str, t_exec: float, host: float, detail: str) -> None:
        """Record something that happened to the agent on its control channel."""
        self.record(
            Channel.CONTROL,
            {
                "event": kind, "command": None, "at": None, "t_exec": t_exec,
                "t_sim": self.sim_time(t_exec), "host_monotonic": host,
                "mode": self.run_state.mode, "detail": detail,
            },
        )  # fmt: skip

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> None:
        """Declare everything; refuse (NameTaken) if the name is already in the federation.
        The platform starts held until its run starts (``waiting``)."""
        self.safety.enforce()  # held (waiting) until its run starts
        s, cfg = self.session, self.config
        callback = zenoh.handlers.Callback
        fed = cfg.federation
        if name_alive(s, self.key(self.me)):
            raise NameTaken(
                f"agent {self.me} is already in federation {fed}: "
                "stop it first or choose another --name"
            )
        self._declared.append(
            s.declare_queryable(
                self.key(self.me, "sync"), callback(self.on_sync_query, indirect=False)
            )
        )
        # Best effort: a router with a UDP link beside its TCP one (deploy/routers) sends
        # pose there, so a pose never waits behind a lost TCP segment; the next pose
        # supersedes a lost one. Sync, control and status stay reliable.
        self._pose_pub = s.declare_publisher(
            self.key(self.me, "pose"), express=True, reliability=zenoh.Reliability.BEST_EFFORT
        )
        self.reporter.publisher = s.declare_publisher(self.key(self.me, "status"))
        self._declared += [self._pose_pub, self.reporter.publisher]
        self._pose_pub_id = self._pose_pub.id  # read once: each read builds a new object
        self._subscribe_poses()
        self._declared += self.role.start(s)
        self._declared.append(
            s.declare_subscriber(
                keys.control_key(fed), callback(self.commands.on_control, indirect=False)
            )
        )
        self._declared.append(
            s.liveliness().declare_subscriber(
                keys.all_agents(fed), callback(self.on_liveliness, indirect=False), history=True
            )
        )
        if self.rejoining.policy != "never":  # the runs under way others announce
            self._declared.append(
                s.declare_subscriber(
                    keys.all_of(fed, "status"), callback(self.rejoining.on_status, indirect=False)
                )
            )
        if cfg.runs_dir is not None:
            software_versions()  # now, not on Zenoh's thread when a run arms (git: up to 2 s)
            self.recording_server = RecordingServer(
                s, fed, self.me, cfg.runs_dir, busy=self.commands.busy,
                min_free_mb=cfg.record_min_free_mb,
            )  # fmt: skip
        self._declared.append(s.liveliness().declare_token(self.key(self.me)))
        if self.fanout is None:  # a session of its own (a host watches its shared one)
            self._declared += watch_routers(s, f"agent {self.me}")
        self.watches.started(time.monotonic())
        if cfg.status_json is not None:
            path = Path(cfg.status_json)
            path.parent.mkdir(parents=True, exist_ok=True)
            self.reporter.status_file = path.open("a", encoding="utf-8")
        log.info("agent %s (%s) up in federation %s", self.me, cfg.role, fed)

    def _subscribe_poses(self) -> None:
        """Every pose (``watch_all``) or the followed agent's, on a shared feed where one
        serves, else on the session's fan-out or a subscriber of its own."""
        cfg = self.config
        watched = keys.all_of(cfg.federation, "pose") if cfg.watch_all else None
        if watched is None and self.follow is not None:
            watched = self.key(self.follow, "pose")
        role = self.role
        if watched is not None and not cfg.watch_all and role.kind == "follower":
            # The leader's and its stand-in's poses: the holder's alone count (follow).
            assert role.stand_in is not None
            for key in (watched, self.key(role.stand_in, "pose")):
                self._declared.append(
                    self.session.declare_subscriber(
                        key, zenoh.handlers.Callback(self.intake.on_pose_sample, indirect=False)
                    )
                )
            return
        if watched is None or self.intake.join_feed(watched):
            return
        self._declared.append(
            self.fanout.subscribe(watched, self.intake.on_pose)
            if self.fanout is not None
            else self.session.declare_subscriber(
                watched, zenoh.handlers.Callback(self.intake.on_pose_sample, indirect=False)
            )
        )

    def close(self, wait: bool = True) -> None:
        """Undeclare everything (tokens and subscribers first); the caller closes the session.

        With ``wait`` a run's recording is finished (its manifest written) first, while
        the name is still this agent's: a process started under it at once would
        otherwise find the run unfinished and recover it beside the finish. Without
        (``fedlab host``, whose other agents fly on), it finishes on its own thread
        (:attr:`finishing`), which the caller joins."""
        self.commands.closing = True  # no command but an abort is taken from here on
        self.safety.apply(Trigger.ENDED)  # leave the platform with every valve closed
        try:
            self.platform.close()  # a serial platform sends all-closed and releases its port
        except Exception as error:
            log.warning("closing the platform failed: %s", error)
        self.recordings.close(wait=wait)
        undeclare_all(self._declared)
        for feed in self.links.leave_feeds(self):  # the last agent on it unsubscribes
            undeclare_all([feed.subscription] if feed.subscription is not None else [])
        emptied, orphaned = self.links.leave(self)
        for link in emptied:
            if link.querier is not None:
                link.querier.close()
        for link in orphaned:  # the agents still on it look for a sender again
            for user in link.agents:
                user.peer_table.look_again()
        if self.recording_server is not None:
            self.recording_server.close()
            self.recording_server = None
        self.reporter.close()
        self.recordings.close_file()

    def run(self, stop: threading.Event) -> None:
        """The agent's loop, until ``stop`` is set or the configured duration has passed.

        Periodic tasks on one thread: the platform's control step (its ``rate``,
        100 Hz for simulated platforms), pose publication (``pose_rate``), sync
        requests (``sync_period``) and status (``status_period``). A missed tick is
        skipped, not made up, and counted in ``loop_overruns``. An armed start, freeze or
        resume is a deadline of its own, so it applies on time, not at the next tick.
        """
        run_together([self], stop)

    def end(self) -> None:
        """Its duration has passed: every valve closed first (co-hosted agents may fly on
        for longer), then the last status (a put or a file write that waits no longer
        delays the hold)."""
        try:
            self.safety.apply(Trigger.ENDED)
        finally:
            self.publish_status()

    # -- time ------------------------------------------------------------------------
    def reference_offset(self, t_exec: float) -> float | None:
        """Reference clock minus own clock (0 on the reference itself)."""
        return self.timebase.reference_offset(t_exec)

    def sim_time(self, t_exec: float) -> float | None:
        """Simulation time (Eq. 5): the reference agent's clock."""
        return self.timebase.sim_time(t_exec)

    def transition_due(self) -> float:
        """Host monotonic time at which an armed start, freeze or resume applies (inf if
        none is armed): a deadline of the loop's own, so that it applies on time, not at
        the next control tick."""
        due = self.run_state.due
        if due is None:
            return math.inf
        t_exec, host = self.clock.read()
        t_sim = self.timebase.sim_time(t_exec)
        if t_sim is None:
            return math.inf
        return host + (due - t_sim) / self.clock.rate

    # -- the agent's own loop --------------------------------------------------------
    def reference_heading(
        self, t_exec: float, run_time: float | None, t_sim: float | None = None
    ) -> tuple[float, float]:
        """Guidance: the leader's maneuver on run time, or the followed heading
        (``t_sim``: simulation time at ``t_exec``, if known: the followed agent's clock
        when it is the reference, so not estimated twice in one step)."""
        if self.config.role in ("leader", "stand-in"):
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
        # The maneuver (as the followed platform flies it) is the filter's input only
        # while the run's time runs.
        profile = None
        if run_time is not None and self.run_state.mode == "running":
            profile = self.followed_model.profile(self.maneuver, run_time)
        return self.heading_estimator.reference(
            received, now, self.config.latency_compensation, profile, run_time
        )

    def control_step(self) -> None:
        """Run state, watches, guidance and one platform step (the platform's rate)."""
        if self.config.clock_step is not None:
            self._rehearse_clock_step()
        t_exec, host = self.clock.read()
        self.watches.look(host)
        t_sim = self.sim_time(t_exec)
        self.rejoining.look(t_exec, host, t_sim)
        events, run_time = self.commands.update(t_sim)
        if events:
            self.commands.apply(events, t_exec, host)
            if any(e.kind in ("frozen", "resumed") for e in events):
                self.commands.status_now = True  # ctl waits to see it applied
        self.role.step(t_exec, host, t_sim)  # before the link's watch: whom it follows
        self.watches.step(t_exec, host)
        restored = self.safety.enforce()  # a step never runs free while a hold stands
        if restored is not None:
            self.count(Count.HOLDS_RESTORED)
            log.warning(
                "run %s: the platform was released; held again (%s)", self.run_state.mode, restored
            )
        self.guidance = self.reference_heading(t_exec, run_time, t_sim)
        if self.scenario is not None:
            if self.commands.scenario_new_run:
                self.commands.scenario_new_run = False
                self.scenario.new_run()
            self._scenario_reference(t_exec, t_sim, run_time)
        if self.run_state.mode == "running":  # a rejoined platform captures its reference
            self.guidance = self.rejoining.guidance(*self.guidance, host)
            self.guidance = self.role.guidance(*self.guidance, host)  # and after a switch
        else:
            self.rejoining.pause(host)
            self.role.pause(host)
        self.guidance_at = (t_exec, host, t_sim, run_time)
        self.pose = self.platform.step(t_exec, *self.guidance, self.track)
        self.watches.watch_area(t_exec, host)
        # A hold that blocks a start, set or lifted, is reported at this step, not at the
        # next periodic status (up to a second on): preflight reads the latest status, and
        # one that shows a stale link's hold already lifted would refuse a start.
        blocking = self.safety.blocking()
        if blocking != self._blocking_shown:
            self._blocking_shown = blocking
            self.commands.status_now = True
        if self.commands.status_now:
            self.commands.status_now = False
            self.publish_status()

    def _scenario_reference(
        self, t_exec: float, t_sim: float | None, run_time: float | None
    ) -> None:
        """The scenario's 3-DOF reference from the others' poses on reference time."""
        assert self.scenario is not None
        frozen = self.run_state.mode == "frozen"
        others = self.intake.others(self.clock.now())
        ref = self.scenario.reference(t_sim, run_time, others, self.pose, frozen)
        if ref is not None:
            self.guidance = (ref.heading, ref.rate)
            self.track = ref.track

    def others(self) -> dict[str, tuple[float, wire.Pose]]:
        """Every other agent's latest pose, stamped on reference time."""
        return self.intake.others(self.clock.now())

    def _rehearse_clock_step(self) -> None:
        step = self.config.clock_step
        if step is not None and not self._clock_stepped and self.clock.now() >= step[0]:
            self._clock_stepped = True
            self.clock.step(step[1])
            log.warning("rehearsal: the execution clock jumps %+.3f s", step[1])

    def step(self) -> None:
        """One control step, then publish the pose."""
        self.control_step()
        self.publish_pose()

    def publish_pose(self) -> None:
        """Publish the platform's estimate with its reference stamp; record what is
        recorded. A pose before the first fix or not finite is never sent."""
        if not self.platform.has_fix:
            # Its prior is not a pose: a follower would steer by it, a formation pull
            # towards it.
            self.count(Count.POSE_WITHHELD_NO_FIX)
            return
        t_exec, host = self.clock.read()
        try:
            payload = wire.encode_pose(t_exec, self.pose)
        except ValueError:
            # Not a pose (NaN or infinity): never sent, and the platform that made it
            # held (the GNC chain's own guard holds first; this covers any platform).
            self.count(Count.POSE_NOT_FINITE)
            if not self.safety.holds(Hold.NONFINITE):
                self.safety.apply(Trigger.POSE_NONFINITE)  # for good: nothing lifts it
                log.error("own pose not finite (%s): not sent, platform held", self.pose)
            return
        self._pose_pub.put(
            payload, source_info=self._source_info(), attachment=self.reference_stamp(t_exec)
        )
        if self.recordings.recorded:  # only the messages of recorded channels are built
            self._record_pose(t_exec, host)

    def _record_pose(self, t_exec: float, host: float) -> None:
        recorded = self.recordings.recorded
        stamp = {"t_exec": t_exec, "host_monotonic": host}
        if Channel.POSE_SENT in recorded:
            self.record(Channel.POSE_SENT, stamp | self.pose._asdict())
        if Channel.REFERENCE in recorded:
            # The reference as computed at the last control step, stamped with that step's time.
            g_exec, g_host, g_sim, g_run = self.guidance_at
            self.record(
                Channel.REFERENCE,
                {
                    "t_exec": g_exec, "host_monotonic": g_host, "t_sim": g_sim,
                    "run_time": g_run, "heading_ref": self.guidance[0],
                    "rate_ref": self.guidance[1], "mode": self.run_state.mode,
                    "valves_open": sum(self.platform.valves),
                }
                | ({} if self.scenario is None else self.scenario.fields())
                | ({"holder": self.role.holder()} if self.role.active else {}),
            )  # fmt: skip
        truth = self.platform.truth if Channel.TRUTH in recorded else None
        if truth is not None:
            self.record(Channel.TRUTH, stamp | truth._asdict())

    def _source_info(self) -> zenoh.SourceInfo:
        """This session's id on each pose sample: a follower tells two sources apart."""
        self._pose_sn += 1
        return zenoh.SourceInfo(self._pose_pub_id, self._pose_sn)

    def reference_stamp(self, t_exec: float) -> bytes:
        """The attachment of a pose stamped ``t_exec`` (wire.encode_stamp): its reference
        time and error bound: this agent's one-way delay to the reference (the median,
        which is no less than half the fastest round trip) plus its estimate's own bound
        (half the weighted round-trip excess of the exchanges it averages), so that
        ``|t_ref - truth| <= bound`` holds whatever queueing the exchanges met (the
        minimum path's own asymmetry is at most half its round trip)."""
        if self.reference == self.me:
            return wire.encode_stamp(self.ref_id, t_exec, 0.0)
        client = self.peer_table.client_of(self.reference)
        offset = None if client is None else client.offset_at(t_exec)
        delay = None if client is None else client.delay
        spread = None if client is None else client.estimator.bound
        if offset is None or delay is None:
            return wire.encode_stamp(self.ref_id, None, None)
        return wire.encode_stamp(self.ref_id, t_exec + offset, delay + (spread or 0.0))

    def send_sync_requests(self, now: float | None = None) -> None:
        """Query every agent due at host monotonic ``now`` (default: the present)."""
        self.peer_table.send_sync_requests(now)

    def due_for_sync(self, now: float) -> list[AgentId]:
        """The agents due for a sync request at host monotonic ``now``."""
        return self.peer_table.due_for_sync(now)

    # -- status ----------------------------------------------------------------------
    def status(self) -> Status:
        return self.reporter.status()

    def readiness(self, t_exec: float) -> Readiness:
        """What preflight checks: platform, recording, the reference clock's estimate."""
        return self.reporter.readiness(t_exec)

    def counter_snapshot(self) -> dict[Count, int]:
        return self.reporter.snapshot()

    def loop_stats(self) -> dict[str, float]:
        return self.reporter.loop_stats()

    def publish_status(self) -> None:
        self.reporter.publish()

    def contested(self) -> dict[str, str]:
        """Every contested peer and why (status)."""
        return self.intake.contested(self.clock.read()[1])

    # -- Zenoh callbacks: quick, and never raise -------------------------------------
    def on_sync_query(self, query: zenoh.Query) -> None:
        """A sync request: ``t2`` read on arrival, the reply (the paper's 64 bytes, the
        send time in the attachment) sent at once."""
        t2 = self.clock.now()  # read on arrival: the paper's t2
        if serve_query(query, functools.partial(self._answer_sync, t2, query.key_expr)):
            self.count(Count.SYNC_REQUESTS_SERVED)

    def _answer_sync(self, t2: float, key: object, payload: zenoh.ZBytes | None) -> Served | None:
        """The reply to a sync request received at ``t2`` (None: dropped, counted)."""
        if payload is not None and self.intake.oversized(
            len(payload), Count.SYNC_REQUESTS_OVERSIZED
        ):
            return None
        request = b"" if payload is None else payload.to_bytes()
        try:
            served = serve(request, t2, self.pose, self.clock.now())
        except wire.DecodeError as error:
            self.count(Count.SYNC_REQUESTS_MALFORMED)
            self.reject("sync request", f"{key}: {error}")
            return None
        return served.payload, served.attachment

    def on_liveliness(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.config.federation, str(sample.key_expr))
            if parsed is None or parsed[1] is not None or parsed[0] == self.me:
                return
            self.peer_seen(parsed[0], sample.kind == zenoh.SampleKind.PUT)
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)

    def peer_seen(self, agent: AgentId, alive: bool) -> None:
        """Liveliness news of another agent: joined (``alive``) or left."""
        if self.peer_table.seen(agent, alive):
            self.intake.forget(agent)  # a restarted agent has a new session id
        log.info("agent %s %s", agent, "joined" if alive else "left")

    # -- a sync link's calls (federation.runtime.links.LinkUser) ---------------------
    def admit_reply(
        self, link: SyncLink, source: str | None, size: int, host: float, feed: PoseFeed | None
    ) -> bool:
        return self.intake.admit_reply(link, source, size, host, feed)

    def sync_requested(self, agent: AgentId, host: float) -> None:
        self.peer_table.silence.requested(agent, host)

    def sync_answered(self, agent: AgentId) -> None:
        self.peer_table.silence.answered(agent)

    def clock_stepped(self, agent: AgentId, jump: float, t3: float, host: float) -> None:
        """``agent``'s clock stepped by ``jump`` s (or this agent's own did): its poses
        count time afresh, so their order is forgotten; the reference's ends a ctl run
        here (run time would jump by it)."""
        self.count(Count.CLOCK_STEPS)
        self.event("clock_step", t3, host, f"{agent}: {jump:+.6f} s")
        self.intake.forget_order(agent)
        if agent == self.reference:
            detail = f"{agent}'s clock stepped {jump:+.3f} s against this agent's"
            self.commands.end_run_here(Count.REFERENCE_CLOCK_STEPS, detail, host)

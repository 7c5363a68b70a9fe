"""An agent (re)started while its run is under way: the run's announcements heard, the
rejoin decided (:mod:`federation.core.rejoin`) and applied, and the joining platform's
reference captured (:mod:`federation.core.capture` for the heading,
:mod:`federation.core.track_capture` for a formation's or docking's position).

Every agent's status is heard (Zenoh's thread keeps only the newest announcement of
each). While the agent waits, its loop asks :func:`~federation.core.rejoin.decide`
every :data:`LOOK_PERIOD`; a decision to join is applied to the run state in one
section under the safety lock (the supervisor hears ``run_rejoined``: it lifts
``waiting``, nothing else), and from the next step its heading reference is captured
at bounded rate and acceleration until it meets the scenario's; a formation's or
docking's position reference (a track) is captured likewise at bounded speed and
acceleration (:func:`track_limits_of`), while the run runs and while it is frozen (the
frozen track is a point the platform holds: it is brought there, not stepped to).

A hold in a run under way (a stale link, however long: past the link's lease the
followed agent leaves and comes back, its sync estimate starts afresh; a contest, a lost
router, the leader's role) leaves the run running on its own clock, the platform held:
it flies on once the hold lifts, at the run's present time. Its reference has moved on
meanwhile (a leader turning at 0.1 rad/s for 30 s is 3 rad further), so the release
goes through the same capture as a rejoin: heading and track from where the platform
is, at bounded rate and acceleration (:meth:`Rejoining.after_hold`); so does a
platform held from its run's first step (a stale link at the start), released later.
The run's own start captures nothing: ``waiting`` is lifted as it starts.

What stays uncapturable (:func:`uncapturable`, :meth:`Rejoining.keep_out`), each with
why in the status's ``rejoin``:

- a plug-in scenario's reference: no capture is known for what it asks;
- a docking target that drifts or turns: its reference counts from where it stood at
  the run's start, which a new process does not know (a still target starts from
  where it is, as at a start);
- a docking chaser before the final approach only: it rejoins while at least the hold
  point's distance from the target (a fresh approach from where it is, then the hold's
  settling and the final approach) and while its way to the hold point, with the
  braking of its present velocity, keeps out of the target's keep-out
  (:func:`federation.core.track_capture.docking_keep_out`); nearer, its earlier run
  may have been in the final approach or at contact, and it stays waiting, held.
"""

from __future__ import annotations

import json
import logging
import threading
from typing import TYPE_CHECKING

from agents.guidance import Track
from federation.core import keys, wire
from federation.core.capture import Capture, Limits
from federation.core.holds import Trigger
from federation.core.rejoin import Announcement, Decision, Situation, announcement, decide
from federation.core.track_capture import BRAKE_SHARE, TrackCapture, TrackLimits, docking_keep_out
from schemas.base import ConfigError
from schemas.experiment import load_experiment
from schemas.platform import PlatformConfig, load_platform
from schemas.scenario import MAX_PATH_SPEED, ScenarioPart

if TYPE_CHECKING:
    import zenoh

    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.services import AgentServices

__all__ = [
    "LOOK_PERIOD",
    "MAX_STEP",
    "TRACKED",
    "Rejoining",
    "limits_of",
    "track_limits_of",
    "uncapturable",
]

log = logging.getLogger("fedlab.agent")

LOOK_PERIOD = 0.2
"""s between two decisions while waiting."""
MAX_STEP = 0.1
"""s: the longest step the capture takes at once (a loop that stalled, a run frozen in
between): it moves on no further than a control step or two would, never by a jump."""


TRACKED = frozenset({"formation", "docking"})
"""Scenario kinds whose reference has a position (a track): captured by
:class:`~federation.core.track_capture.TrackCapture` on a rejoin."""


def uncapturable(scenario: ScenarioPart | None, me: str | None = None) -> str | None:
    """Why agent ``me`` flying ``scenario`` cannot rejoin without a step in its
    reference, as far as its settings tell (a chaser's place is judged at each look,
    :meth:`Rejoining.keep_out`); None: it can. A heading reference (attitude tracking,
    adaptive gains) and a formation's or docking's track have a capture; a plug-in
    scenario's reference has none known, and a drifting or turning docking target's
    counts from where it stood at the start, which a new process does not know."""
    if scenario is None or scenario.kind in ("attitude-tracking", "formation"):
        return None
    if scenario.kind != "docking":
        return (
            f"{scenario.kind}: a plug-in scenario's reference has no capture known (it "
            "could step): no rejoin"
        )
    docking = scenario.docking
    if (
        docking is not None
        and me == docking.target
        and (docking.target_rate_deg != 0.0 or any(v != 0.0 for v in docking.target_drift))
    ):
        return (
            "docking: a drifting or turning target's reference counts from where it stood "
            "at the run's start, which a new process does not know: no rejoin"
        )
    return None


def _preset(platform: str, preset: str | None) -> PlatformConfig:
    """The platform's preset; knatte's for a platform with none (kinematic, a plug-in)."""
    try:
        return load_platform(preset or platform)
    except (ConfigError, ValueError, OSError):
        return load_platform("knatte")


def limits_of(platform: str, preset: str | None) -> Limits:
    """What a heading reference may ask of the platform: its preset's ``max_rate`` and
    its operated torque over its inertia; knatte's for a platform with no preset."""
    config = _preset(platform, preset)
    return Limits(config.max_rate, config.torque / config.inertia)


def track_limits_of(platform: str, preset: str | None) -> TrackLimits:
    """What a position reference may ask of the platform: speed
    :data:`~schemas.scenario.MAX_PATH_SPEED` (the fastest any scenario path may move: a
    preset states no speed of its own) and acceleration its preset's operated thrust
    (one thruster) over its mass, half a thruster pair's force, the deceleration its
    area keeps in reserve too (:class:`agents.workspace.FramedPlatform`); knatte's for a
    platform with no preset."""
    config = _preset(platform, preset)
    return TrackLimits(MAX_PATH_SPEED, config.thrust / config.mass)


class Rejoining:
    """The rejoin of ``owner`` (an agent) into a run its ``commands`` did not start."""

    def __init__(self, owner: AgentServices, commands: RunControl):
        self.owner = owner
        self.commands = commands
        cfg = owner.config
        self.policy = cfg.rejoin_policy
        self.experiment = None if cfg.experiment is None else load_experiment(cfg.experiment).name
        self.limits = limits_of(cfg.platform, cfg.platform_preset)
        self.track_limits = track_limits_of(cfg.platform, cfg.platform_preset)
        self.admitted = False  # an operator's admit (fedlab ctl admit LAB/NAME)
        self._seen: dict[str, Announcement] = {}
        self._lock = threading.Lock()
        self._next_look = 0.0
        self.decision: Decision | None = None  # the last one, for status and preflight
        self.capture: Capture | None = None
        self.track_capture: TrackCapture | None = None
        self._last_host: float | None = None
        self._held_since: float | None = None  # host monotonic a hold in the run began

    def on_status(self, sample: zenoh.Sample) -> None:
        """Another agent's status (Zenoh's thread: never raises, keeps the newest)."""
        try:
            parsed = keys.parse_agent_key(self.owner.config.federation, str(sample.key_expr))
            if parsed is None or parsed[0] == self.owner.me:
                return
            data = json.loads(sample.payload.to_bytes())
            if not isinstance(data, dict):
                return
            seen = announcement(str(parsed[0]), data)
            if seen is None:
                return
            with self._lock:
                self._seen[seen.agent] = seen
        except Exception:  # a malformed status is another agent's problem, not this one's
            log.debug("status on %s not read", sample.key_expr, exc_info=True)

    def look(self, t_exec: float, host: float, t_sim: float | None) -> None:
        """While waiting, every :data:`LOOK_PERIOD`: decide, and join if so."""
        run = self.commands.run_state
        if run.mode not in ("running", "frozen"):
            # A run that ended (aborted, done) captures nothing more.
            self.capture = self.track_capture = None
            self._held_since = None
        if run.mode != "waiting":
            self.admitted = False  # an admit is for the run under way while it waits
            return
        if self.policy == "never":
            self.decision = Decision(False, "rejoin = never")
            return
        if host < self._next_look:
            return
        self._next_look = host + LOOK_PERIOD
        ready = self.owner.readiness(t_exec)
        unready = None
        if not ready.reference_locked:
            unready = "the reference clock's estimate is not locked"
        elif not ready.platform:
            unready = ready.platform_detail or "platform not ready"
        with self._lock:
            seen = tuple(self._seen.values())
        situation = Situation(
            me=str(self.owner.me), reference=str(self.owner.reference),
            experiment=self.experiment, mode=run.mode, policy=self.policy,
            admitted=self.admitted, now=t_sim, seen=seen, unready=unready,
            uncapturable=self.keep_out(t_sim),
        )  # fmt: skip
        decision = decide(situation)
        if self.decision is None or decision.why != self.decision.why:
            log.info("rejoin: %s", decision.why)
        self.decision = decision
        if decision.join:
            self._join(decision, t_exec, host)

    def keep_out(self, t_sim: float | None) -> str | None:
        """Why this agent's reference cannot be captured now (None: it can): its
        settings' answer (:func:`uncapturable`), and a docking chaser judged where it is
        against the target's fresh shared pose (see the module)."""
        scenario = self.owner.config.scenario
        me = str(self.owner.me)
        why = uncapturable(scenario, me)
        if why is not None or scenario is None or scenario.kind != "docking":
            return why
        docking = scenario.docking
        if docking is None or me != docking.chaser:
            return why
        seen = self.owner.others().get(docking.target)
        if seen is None or t_sim is None or abs(t_sim - seen[0]) > docking.lost_after:
            return (
                f"docking: no fresh pose of the target {docking.target} to judge the "
                "keep-out by: no rejoin"
            )
        own, target = self.owner.pose, seen[1]
        return docking_keep_out(
            (own.x, own.y, own.vx, own.vy), (target.x, target.y, target.heading),
            docking.contact_distance, docking.hold_distance,
            BRAKE_SHARE * self.track_limits.max_accel,
        )  # fmt: skip

    def _join(self, decision: Decision, t_exec: float, host: float) -> None:
        owner, commands = self.owner, self.commands
        joined = decision.run
        assert joined is not None and joined.run_id is not None
        assert joined.start_at is not None and joined.duration is not None
        with owner.safety.lock:
            with commands.lock:
                t_sim = owner.sim_time(t_exec)  # the present, as the run state applies it
                events = commands.run_state.rejoin(
                    joined.run_id, joined.start_at, joined.frozen_total, joined.duration, t_sim
                )
                if any(e.kind == "rejoined" for e in events):
                    self.admitted = False  # an admit lets in one rejoin
                    commands.experiment = joined.experiment
                    # The capture begins before the platform is released: its first step
                    # already asks for no more than the platform's limits.
                    self._begin_capture(host)
            for event in events:
                if event.kind == "rejoined":
                    owner.safety.apply_locked(Trigger.RUN_REJOINED)
        commands.apply(events, t_exec, host)
        commands.status_now = True

    def _begin_capture(self, host: float) -> None:
        """Capture the heading and, for a formation or docking, the track from where the
        platform is now (its estimate, common frame)."""
        pose = self.owner.pose
        self.capture = Capture(pose.heading, pose.omega, self.limits)
        scenario = self.owner.config.scenario
        if scenario is not None and scenario.kind in TRACKED:
            self.track_capture = self._track_from(pose)
        self._last_host = host

    def after_hold(self, host: float) -> None:
        """At every step of a run under way (running or frozen): a release after a hold
        seen in it starts a capture from where the platform is (see the module). The
        start's ``waiting`` hold is lifted in the step the run starts, before any is
        seen here."""
        if self.owner.safety.hold is not None:
            if self._held_since is None:
                self._held_since = host
            return
        if self._held_since is not None:
            log.info(
                "released after a %.1f s hold: reference captured from the platform",
                host - self._held_since,
            )
            self._held_since = None
            self._begin_capture(host)

    def _track_from(self, pose: wire.Pose) -> TrackCapture:
        """A position capture that starts at the platform's estimate (common frame)."""
        return TrackCapture(pose.x, pose.y, pose.vx, pose.vy, self.track_limits)

    def _dt(self, host: float) -> float:
        last, self._last_host = self._last_host, host
        return 0.0 if last is None else min(MAX_STEP, max(0.0, host - last))

    def _capture_track(self, capture: TrackCapture, dt: float) -> None:
        """The owner's track this step (``owner.track``), captured in place. No track (a
        docking chaser before its first measurement): nothing to capture, and the
        capture starts afresh from the platform when one comes."""
        owner = self.owner
        track = owner.track
        if track is None:
            self.track_capture = self._track_from(owner.pose)
            return
        owner.track = Track(*capture.step(track, dt))
        if capture.captured:
            log.info("rejoin: position reference captured")
            self.track_capture = None

    def guidance(self, heading: float, rate: float, host: float) -> tuple[float, float]:
        """The heading reference to fly: the scenario's, captured while a rejoin's
        capture lasts; the owner's track (``owner.track``) captured alike, in place."""
        self.after_hold(host)
        capture, track_capture = self.capture, self.track_capture
        if capture is None and track_capture is None:
            return heading, rate
        dt = self._dt(host)
        if track_capture is not None:
            self._capture_track(track_capture, dt)
        if capture is None:
            return heading, rate
        out = capture.step(heading, rate, dt)
        if capture.captured:
            log.info("rejoin: reference captured")
            self.capture = None
        return out

    def pause(self, host: float) -> None:
        """A step not flown on the heading capture (the run frozen, or not running): it
        resumes from here. A frozen run's track (the point the platform holds) is still
        captured: the platform is brought to it, not stepped."""
        frozen = self.commands.run_state.mode == "frozen"
        if frozen:
            self.after_hold(host)
        track_capture = self.track_capture
        if track_capture is not None and frozen:
            self._capture_track(track_capture, self._dt(host))
        elif self.capture is not None or track_capture is not None:
            self._last_host = host

    def admit(self) -> str | None:
        """An operator's admit (``fedlab ctl admit``, Zenoh's thread): why it is refused,
        or None (admitted: the next decision, at the next step, may join)."""
        mode = self.commands.run_state.mode
        if self.policy == "never":
            return "rejoin = never: no admit lets it rejoin"
        if mode != "waiting":
            return f"admit while {mode}: only a waiting agent rejoins"
        self.admitted = True
        self._next_look = 0.0
        return None

    def report(self) -> dict[str, str | None]:
        """The status's ``rejoin`` (why it does not join, while waiting) and ``admit_run``
        (the run it joins once admitted)."""
        decision = self.decision
        if decision is None or self.commands.run_state.mode != "waiting":
            return {"rejoin": None, "admit_run": None}
        run = decision.run if decision.waiting_admit else None
        return {"rejoin": decision.why, "admit_run": None if run is None else run.run_id}

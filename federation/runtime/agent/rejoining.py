"""An agent (re)started while its run is under way: the run's announcements heard, the
rejoin decided (:mod:`federation.core.rejoin`) and applied, and the joining platform's
reference captured (:mod:`federation.core.capture`).

Every agent's status is heard (Zenoh's thread keeps only the newest announcement of
each). While the agent waits, its loop asks :func:`~federation.core.rejoin.decide`
every :data:`LOOK_PERIOD`; a decision to join is applied to the run state in one
section under the safety lock (the supervisor hears ``run_rejoined``: it lifts
``waiting``, nothing else), and from the next step its heading reference is captured
at bounded rate and acceleration until it meets the scenario's.
"""

from __future__ import annotations

import json
import logging
import threading
from typing import TYPE_CHECKING

from federation.core import keys
from federation.core.capture import Capture, Limits
from federation.core.holds import Trigger
from federation.core.rejoin import Announcement, Decision, Situation, announcement, decide
from schemas.base import ConfigError
from schemas.experiment import load_experiment
from schemas.platform import PlatformConfig, load_platform
from schemas.scenario import ScenarioPart

if TYPE_CHECKING:
    import zenoh

    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.services import AgentServices

__all__ = ["LOOK_PERIOD", "MAX_STEP", "Rejoining", "limits_of", "uncapturable"]

log = logging.getLogger("fedlab.agent")

LOOK_PERIOD = 0.2
"""s between two decisions while waiting."""
MAX_STEP = 0.1
"""s: the longest step the capture takes at once (a loop that stalled, a run frozen in
between): it moves on no further than a control step or two would, never by a jump."""


def uncapturable(scenario: ScenarioPart | None) -> str | None:
    """Why an agent flying ``scenario`` cannot rejoin without a step in its reference:
    the capture brings in a heading reference (attitude tracking, adaptive gains), not a
    formation's or docking's position reference. None: it can."""
    if scenario is None or scenario.kind == "attitude-tracking":
        return None
    return f"{scenario.kind}: its position reference has no capture (it would step): no rejoin"


def limits_of(platform: str, preset: str | None) -> Limits:
    """What a reference may ask of the platform: its preset's ``max_rate`` and its
    operated torque over its inertia; knatte's for a platform with no preset
    (kinematic, a plug-in)."""
    config: PlatformConfig
    try:
        config = load_platform(preset or platform)
    except (ConfigError, ValueError, OSError):
        config = load_platform("knatte")
    return Limits(config.max_rate, config.torque / config.inertia)


class Rejoining:
    """The rejoin of ``owner`` (an agent) into a run its ``commands`` did not start."""

    def __init__(self, owner: AgentServices, commands: RunControl):
        self.owner = owner
        self.commands = commands
        cfg = owner.config
        self.policy = cfg.rejoin_policy
        self.experiment = None if cfg.experiment is None else load_experiment(cfg.experiment).name
        self.limits = limits_of(cfg.platform, cfg.platform_preset)
        self.admitted = False  # an operator's admit (fedlab ctl admit LAB/NAME)
        self._seen: dict[str, Announcement] = {}
        self._lock = threading.Lock()
        self._next_look = 0.0
        self.decision: Decision | None = None  # the last one, for status and preflight
        self.capture: Capture | None = None
        self._last_host: float | None = None

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
            self.capture = None  # a run that ended (aborted, done) captures nothing more
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
            uncapturable=uncapturable(self.owner.config.scenario),
        )  # fmt: skip
        decision = decide(situation)
        if self.decision is None or decision.why != self.decision.why:
            log.info("rejoin: %s", decision.why)
        self.decision = decision
        if decision.join:
            self._join(decision, t_exec, host)

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
                    pose = owner.pose
                    self.capture = Capture(pose.heading, pose.omega, self.limits)
                    self._last_host = host
            for event in events:
                if event.kind == "rejoined":
                    owner.safety.apply_locked(Trigger.RUN_REJOINED)
        commands.apply(events, t_exec, host)
        commands.status_now = True

    def guidance(self, heading: float, rate: float, host: float) -> tuple[float, float]:
        """The heading reference to fly: the scenario's, captured while a rejoin's
        capture lasts."""
        capture = self.capture
        if capture is None:
            return heading, rate
        last, self._last_host = self._last_host, host
        dt = 0.0 if last is None else min(MAX_STEP, max(0.0, host - last))
        out = capture.step(heading, rate, dt)
        if capture.captured:
            log.info("rejoin: reference captured")
            self.capture = None
        return out

    def pause(self, host: float) -> None:
        """A step not flown on the capture (the run frozen): it resumes from here."""
        if self.capture is not None:
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

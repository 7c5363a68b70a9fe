"""The run and the operator's commands: the run state, which commands are acted on, and
what became of each.

A command is read (an abort honoured however malformed), admitted by the per-issuer
gate (:class:`~federation.core.commands.CommandGate`), refused if it is not this
agent's (another experiment's participants, an agent closing, a run id recorded
here already), then applied to the run state (:mod:`federation.core.runstate`). The
run's change and the triggers it gives the safety supervisor are decided in one
section under the safety lock: no hold or release is judged between them.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from pydantic import ValidationError

from agents.guidance import ReferenceManeuver
from federation.core.channels import Channel
from federation.core.commands import CommandGate, Verdict
from federation.core.counters import Count
from federation.core.holds import Trigger
from federation.core.runstate import Event, RunState
from schemas.config import ManeuverConfig
from schemas.messages import (
    Command,
    CommandOutcome,
    RunTransition,
    is_abort,
    malformed_outcome,
    validation_reason,
)

if TYPE_CHECKING:
    import zenoh

    from federation.runtime.agent.recordings import Recordings
    from federation.runtime.agent.services import AgentServices

__all__ = ["ACTIVE", "RunControl", "maneuver_of"]

log = logging.getLogger("fedlab.agent")

ACTIVE = frozenset({"armed", "running", "frozen"})
"""Run modes in which a run is under way."""
_LOCAL_ABORT = Command(command="abort", seq=-1, issuer="fedlab (this agent)")
"""The abort an agent gives itself (its reference restarted mid-run, say)."""
_RUN_TRIGGERS = {
    "armed": Trigger.RUN_ARMED,
    "started": Trigger.RUN_STARTED,
    "rejoined": Trigger.RUN_REJOINED,
    "done": Trigger.RUN_DONE,
    "aborted": Trigger.RUN_ABORTED,
}
"""The run state's events the safety supervisor hears (a reset is heard as the
operator's command, applied)."""


def maneuver_of(m: ManeuverConfig) -> ReferenceManeuver:
    """The leader's maneuver a config (or a start command) describes."""
    return ReferenceManeuver(m.still, m.duration, math.radians(m.amplitude_deg))


class RunControl:
    """The run of ``owner`` (an agent) and the commands that drive it; ``recordings``
    record each run."""

    def __init__(self, owner: AgentServices, recordings: Recordings):
        self.owner = owner
        self.recordings = recordings
        cfg = owner.config
        self.run_state = RunState(autostart=not cfg.wait_start, duration=cfg.run_duration)
        self.lock = threading.Lock()  # the run state; taken after the safety lock
        self.gate = CommandGate()  # which commands to act on: per issuer, aborts always
        self.log: deque[CommandOutcome] = deque(maxlen=8)
        self.closing = False  # no command but an abort is taken once set
        self.status_now = False  # a command was applied: report it at the next step
        self.experiment: str | None = None  # the experiment the run's start named
        # An operator's admit: why it is refused, or None (the agent's rejoin takes it).
        self.admit: Callable[[], str | None] = lambda: "this agent rejoins no run"
        # An operator's handback to a leader (the role's): whether it concerns this agent
        # (its leader or stand-in), and why it changed nothing, or None.
        self.handback_concerns: Callable[[str], bool] = lambda leader: False
        self.handback: Callable[[str, float], str | None] = lambda leader, t: "no role kept"
        # The run (id, start) the scenario's guidance is for; a new one is begun on the
        # loop's thread at its next step, not under a reference it is computing.
        self._scenario_run: tuple[str | None, float | None] | None = None
        self.scenario_new_run = False

    @property
    def mode(self) -> str:
        return self.run_state.mode

    # -- the loop's side -------------------------------------------------------------
    def update(self, t_sim: float | None) -> tuple[list[Event], float | None]:
        """Advance the run to reference time ``t_sim`` (a start reached, a duration
        passed) and tell the supervisor, in one section; its events and run time."""
        with self.owner.safety.lock:
            with self.lock:
                events = self.run_state.update(t_sim)
                run_time = self.run_state.run_time(t_sim)
            self._tell_safety(events)
        return events, run_time

    def end_run_here(self, counter: Count, detail: str, host: float) -> None:
        """Abort a run started by ctl (armed, running or frozen) on this agent alone: the
        reference it counts time on is no longer the one the run began with (restarted,
        or its clock stepped), or it cannot fly safely (no router, the estimate
        restarted). Every valve closed, ``counter`` counted, ``detail`` in the log and
        the recording; nothing outside a ctl run."""
        owner = self.owner
        t_exec = owner.clock.at(host)
        state = self.run_state
        with owner.safety.lock:  # before anything else is said or recorded: valves closed
            with self.lock:
                if state.run_id is None or state.mode not in ACTIVE:
                    return
                owner.safety.close_valves()
                events = state.command(_LOCAL_ABORT, owner.sim_time(t_exec))
            self._tell_safety(events)
        owner.count(counter)
        log.error("run %s: %s: aborted here", state.run_id, detail)
        self.apply([dataclasses.replace(e, detail=detail) for e in events], t_exec, host)
        self.status_now = True

    def transitions(self) -> dict[str, RunTransition | None]:
        """The status's ``transition`` (the last applied) and ``armed`` (a freeze or
        resume to come) fields."""
        state = self.run_state
        with self.lock:
            last, armed = state.last, state.armed
        applied = None
        if last is not None:
            applied = RunTransition(
                event=last.kind, at=last.at, run_time=last.run_time, detail=last.detail
            )
        return {
            "transition": applied,
            "armed": None if armed is None else RunTransition(event=armed[0], at=armed[1]),
        }

    def busy(self) -> str | None:
        """Why recordings are not served now: a run started by ctl armed, running or
        frozen (its poses and sync replies go first on this agent's links)."""
        state = self.run_state
        if state.run_id is None or state.mode not in ACTIVE:
            return None  # an agent on its own runs from reference time 0 for good
        return f"run {state.run_id} {state.mode}"

    # -- a command arrives -----------------------------------------------------------
    def on_control(self, sample: zenoh.Sample) -> None:
        """A sample on the federation's control key (Zenoh's thread: never raises)."""
        owner = self.owner
        t_exec, host = owner.clock.read()
        try:
            command = self._read(sample)
            if command is None:
                return
            owner.count(Count.CONTROL_RECEIVED)
            events = self._act(command, t_exec)
            if events is None:
                return
            ignored = [e.detail for e in events if e.kind == "ignored"]
            if ignored:
                owner.count(Count.COMMANDS_IGNORED)
            self.outcome(command, "ignored" if ignored else "applied", "; ".join(ignored))
            self._record(command, t_exec, host)
            self.apply(events, t_exec, host)
            self.status_now = True  # ctl waits for it: at the next step, not in a second
        except Exception:
            log.exception("control sample on %s failed", sample.key_expr)

    def _act(self, command: Command, t_exec: float) -> list[Event] | None:
        """Apply an admitted command; None if the gate dropped it. An abort goes first,
        before the gate is asked: every valve closed and the run aborted, under the
        safety lock, so no release judged on the loop's thread can follow its hold."""
        if command.command == "abort":
            events = self._run(command, t_exec)
            verdict = self.gate.admit(command.command, command.issuer, command.seq)
            return events if self._admitted(command, verdict) else None
        verdict = self.gate.admit(command.command, command.issuer, command.seq)
        if not self._admitted(command, verdict):
            return None
        if command.command == "handback":  # the leader's and its stand-in's business
            assert command.participants
            leader = command.participants[0]
            if not self.handback_concerns(leader):
                return None
            refused = self.handback(leader, t_exec)
            if refused is None:
                return []
            return [Event("ignored", self.owner.sim_time(t_exec), refused)]
        refused = self._not_mine(command)
        if refused is None and command.command == "start":
            refused = self.recordings.recorded_before(command.run_id)
        if refused is None and command.command == "admit":  # no run state's business
            refused = self.admit()
            if refused is None:
                return []
        if refused is not None:  # refused before the run state sees it
            return [Event("ignored", self.owner.sim_time(t_exec), refused)]
        return self._run(command, t_exec)

    def _read(self, sample: zenoh.Sample) -> Command | None:
        """The command in ``sample``; None (counted, logged, reported to ctl where it
        names itself) if it does not validate, except an abort, honoured however
        malformed the rest of it is."""
        payload = sample.payload.to_bytes()
        try:
            return Command.model_validate_json(payload)
        except ValidationError as error:
            self.owner.count(Count.CONTROL_MALFORMED)
            why = validation_reason(error)
            self.owner.reject("control command", f"{sample.key_expr}: {why}")
            if is_abort(payload):
                return Command(command="abort", seq=-1, issuer="malformed")
            reported = malformed_outcome(payload, why)
            if reported is not None:  # ctl says why, not "command not seen"
                self.log.append(reported)
            return None

    def _admitted(self, command: Command, verdict: Verdict) -> bool:
        """Whether the gate let ``command`` through; a drop counted, logged and reported
        (a repeat only counted: ctl publishes each command 3 times)."""
        if verdict.admitted:
            return True
        if verdict.outcome == "repeat":
            self.owner.count(Count.COMMANDS_REPEATED)
            return False
        self.owner.count(Count.COMMANDS_DROPPED)
        self.outcome(command, verdict.outcome, verdict.detail)
        log.warning(
            "dropped %s from %s: %s (%s)",
            command.command, command.issuer, verdict.outcome, verdict.detail,
        )  # fmt: skip
        return False

    def _run(self, command: Command, t_exec: float) -> list[Event]:
        """Apply ``command`` to the run state and tell the supervisor what came of it, in
        one section under the safety lock. An abort closes every valve first; a reset
        applied (not ignored) is the operator's, whatever the run's mode."""
        owner = self.owner
        with owner.safety.lock:
            if command.command == "abort":
                owner.safety.close_valves()
            with self.lock:
                events = self.run_state.command(command, owner.sim_time(t_exec))
                if any(e.kind == "armed" for e in events):
                    self.experiment = command.experiment
                    if command.maneuver is not None:
                        owner.maneuver = maneuver_of(command.maneuver)
            self._tell_safety(events)
            if command.command == "reset" and not any(e.kind == "ignored" for e in events):
                owner.platform.acknowledge_restart()
                owner.safety.apply_locked(Trigger.OPERATOR_RESET)
        return events

    def _tell_safety(self, events: Iterable[Event]) -> None:
        """The triggers of run-state ``events``, the safety lock held by the caller."""
        for event in events:
            trigger = _RUN_TRIGGERS.get(event.kind)
            if trigger is not None:
                self.owner.safety.apply_locked(trigger)

    def _not_mine(self, command: Command) -> str | None:
        """Why a command is not for this agent: it is closing (its recording finishing:
        a run it armed no one would finish), or the command names the participants and
        not this one (a start for one experiment arms only its participants, each
        preflighted and awaited by ctl)."""
        if self.closing:
            return "this agent is stopping"
        return command.not_for(str(self.owner.me))

    def outcome(self, command: Command, outcome: str, detail: str) -> None:
        """Remember what became of a command: status reports the last few, so ctl can
        say why an agent did not confirm."""
        self.log.append(
            CommandOutcome(
                command=command.command, issuer=command.issuer[:200], seq=command.seq,
                outcome=outcome, detail=detail,
            )
        )  # fmt: skip

    def _record(self, command: Command, t_exec: float, host: float) -> None:
        owner = self.owner
        owner.record(
            Channel.CONTROL,
            {
                "event": "command", "command": command.model_dump(), "at": command.at,
                "t_exec": t_exec, "t_sim": owner.sim_time(t_exec), "host_monotonic": host,
                "mode": self.run_state.mode, "detail": "",
            },
        )  # fmt: skip

    # -- what follows a run's events -------------------------------------------------
    def apply(self, events: list[Event], t_exec: float, host: float) -> None:
        """Act on run-state events (the supervisor has heard them): a new recording and
        the scenario's new run when a start arms; log and record each; a run's
        recording finished when it ends."""
        owner = self.owner
        for event in events:
            if event.kind == "armed":
                self._armed()
            elif event.kind == "rejoined":
                self._armed(segment=True)
            level = logging.WARNING if event.kind in ("aborted", "ignored") else logging.INFO
            log.log(
                level, "run %s %s at reference time %s %s",
                self.run_state.run_id or "-", event.kind, event.t_sim, event.detail,
            )  # fmt: skip
            owner.record(
                Channel.CONTROL,
                {
                    "event": event.kind, "command": None, "at": self.run_state.start_at,
                    "t_exec": t_exec, "t_sim": event.t_sim, "host_monotonic": host,
                    "mode": self.run_state.mode, "detail": event.detail,
                    "run_time": self._run_time_at(event),
                },
            )  # fmt: skip
            if event.kind in ("aborted", "done"):
                self.recordings.end_run()

    def _run_time_at(self, event: Event) -> float | None:
        """The run time at a transition ``event`` applied (as :attr:`RunState.last` has
        it), None for any other event."""
        last = self.run_state.last
        if last is None or (last.kind, last.at) != (event.kind, event.t_sim):
            return 0.0 if event.kind == "started" else None
        return last.run_time

    def _armed(self, segment: bool = False) -> None:
        """A run armed (``segment``: rejoined): the scenario's guidance begins anew and
        the run is recorded (rejoined: as its next segment)."""
        owner, state = self.owner, self.run_state
        run = (state.run_id, state.start_at)
        if owner.scenario is not None and run != self._scenario_run:
            self._scenario_run = run  # nothing of the last run's guidance carries over
            self.scenario_new_run = True
        cfg = owner.config
        settings: dict[str, object] = {
            "role": cfg.role, "follow": cfg.follow,
            "latency_compensation": cfg.latency_compensation,
            "reference": str(owner.reference), "duration": state.duration,
        }  # fmt: skip
        if segment:
            self.recordings.begin_segment(state.run_id, settings)
        else:
            self.recordings.begin_run(state.run_id, settings)

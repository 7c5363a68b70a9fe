"""Run modes of an experiment, free of I/O: commands in, mode and run time out.

::

    waiting --start(at)--> armed --t_sim >= at--> running --freeze(at)--> freezing
      ^  ^                  |  ^                   |   ^                    |
      |  |                  |  +--start (re-arm)   |   |             t_sim >= at
      |  +------reset-------+                      |   |                    v
      |                                            |   +-- resuming <----- frozen
      |                                            |  t_sim >= at   resume(at)
      |                                  run_time >= duration
      |                                            v
      +------------reset----------------------- done --start--> armed
    any mode --abort--> aborted --reset--> waiting

``freezing`` and ``resuming`` are stages, not modes: a run whose freeze is announced
for an instant to come is still ``running`` (its platforms fly on until then), one
whose resume is announced still ``frozen``. A freeze or resume whose instant has come
applies at once, as before (``running`` to ``frozen``, ``frozen`` to ``running``).

The rules :meth:`RunState.command` keeps (which commands reach it at all is decided
first by :class:`federation.core.commands.CommandGate`):

1. ``abort`` aborts from any mode; aborted again, nothing happens (idempotent).
2. ``reset`` brings an aborted, done or armed run back to waiting (an operator's
   explicit act after an abort); while waiting it does nothing; while running or
   frozen it is ``ignored`` (abort first).
3. After an abort every other command is ``ignored`` until a reset.
4. ``start`` arms (``at``, or the present reference time without one) from waiting,
   done or armed (re-arm) and starts at once if that time has come; while running
   or frozen it is ``ignored``; without ``at`` and unsynchronized it is ``ignored``.
   It names the run (``run_id``) and may give its ``duration`` (s of run time).
   A start without a ``duration``, for a run state without a default one, is
   ``ignored``: a run must end.
5. ``freeze`` only while running, ``resume`` only while frozen, each at ``at`` (not
   earlier than the run's start, its last resume or the freeze) or the present. An
   ``at`` to come arms the transition (``freezing``, ``resuming``): it applies when the
   reference time reaches it, on every agent at the same instant of the run. A
   resume's ``at`` more than ``LATE_START`` past is ``ignored``, as a start's is; a
   freeze's makes it freeze at the present, and a freeze applied after its instant
   says how late it came. A resume whose ``at`` is before the freeze's instant (armed
   or applied) is ``ignored``: the run would resume before it froze. A second freeze
   while one is armed, or a second resume while one is armed, keeps the earlier
   instant (whatever order two operators' commands arrive in, every agent keeps the
   same one); a resume while a freeze is armed, or a freeze while a resume is armed,
   is ``ignored`` (the armed one applies first; an abort ends either). Anything else
   is ``ignored``.
6. A start or resume without ``at`` acts on receipt, unless its ``issued_at`` (the
   reference time it was sent) is more than ``LATE_START`` past: ``ignored`` (it waited
   behind a cut link; acted on now, it would set platforms moving when no one chose).
   A resume with neither is ``ignored`` (ctl stamps every resume). A freeze acts on
   receipt however late, and without the reference time at the last one known.
7. ``admit`` and ``handback`` do nothing to a run state in any mode: an admit lets a
   waiting agent rejoin a run under way, which :mod:`federation.core.rejoin` decides and
   :meth:`RunState.rejoin` applies; a handback gives the leader's role back to a deposed
   leader (:mod:`federation.core.standin`).

What each command does in each mode and stage (rules 1 to 5 and 7 without their
instants) is one table, :data:`COMMAND_RULES`. What a table cannot say, whether a command
came in time, is a few named checks: those of rule 6 and a resume's instant run before the table's
rule (:data:`TIMING_CHECKS`; after an abort none runs, rule 3 answers first), and a
start's own (not synchronized, instant passed, no duration) once its mode lets it arm.

:meth:`RunState.update` makes the transitions no command makes: armed to running
once the reference time reaches the start, an armed freeze or resume once it reaches
its instant, running to done once the run time reaches the duration (a freeze armed
for after the run's end never applies). :attr:`RunState.last` is the last transition
applied: its instant on reference time and the run time then.

:meth:`RunState.rejoin` joins, from ``waiting``, a run under way that others announce
(:mod:`federation.core.rejoin` decides whether): ``running`` at once, with the run's id,
start instant, time frozen and duration, so its run time is theirs (event ``rejoined``).

``run_time`` is the experiment's clock: reference time since the start, less the
time spent frozen. The leader's maneuver is a function of it.

``autostart`` (a lone agent, no ``ctl start``): the run starts at the first
update with a reference time, so the run time counts from when the agent is
ready, not from its clock's zero.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Literal, Protocol, get_args

__all__ = [
    "HOLD_MODES",
    "MOVING_MODES",
    "Applied",
    "Event",
    "Mode",
    "RunCommand",
    "RunState",
    "Stage",
]

Mode = Literal["waiting", "armed", "running", "frozen", "done", "aborted"]
Stage = Literal[Mode, "freezing", "resuming"]
"""A mode, or a run with a freeze (``freezing``: still running) or a resume
(``resuming``: still frozen) armed for an instant to come."""

HOLD_MODES: frozenset[str] = frozenset({"waiting", "armed", "done", "aborted"})
"""Modes in which every valve stays closed: a platform moves only in a run under way
(running, or frozen: holding its point). Before its start it waits, held, so that a
real platform fires no valve between its agent's start and an operator's (steering to
heading 0, or after its leader)."""
MOVING_MODES: frozenset[str] = frozenset(get_args(Mode)) - HOLD_MODES
"""Modes in which a platform that nothing else holds is released: running, frozen."""
LATE_START = 1.0
"""s: a start received later than this after its instant is refused (``ignored``)."""


class RunCommand(Protocol):
    """What the run state reads of a command (:class:`schemas.messages.Command` is one)."""

    @property
    def command(self) -> str:
        """``start``, ``freeze``, ``resume``, ``abort`` or ``reset``."""

    @property
    def at(self) -> float | None:
        """Reference time (s) at which to act; None: on receipt."""

    @property
    def run_id(self) -> str | None:
        """The run a start names."""

    @property
    def duration(self) -> float | None:
        """s of run time after which the run is done (None: no end)."""


@dataclass(frozen=True)
class Event:
    """What a transition (or a refused command) did, for the log and the recording."""

    kind: Literal[
        "armed", "started", "rejoined", "freezing", "frozen", "resuming", "resumed", "done",
        "aborted", "reset", "ignored",
    ]  # fmt: skip
    t_sim: float | None  # reference time the event refers to (s)
    detail: str = ""


APPLIED_KINDS = frozenset({"started", "rejoined", "frozen", "resumed", "done", "aborted"})
"""The events that change whether the run's clock runs: :attr:`RunState.last` records them."""


@dataclass(frozen=True)
class Applied:
    """A transition applied: its event, the reference instant it applied at (s) and the
    run time then (s; None for an abort before the start)."""

    kind: str
    at: float | None
    run_time: float | None
    detail: str = ""


Outcome = Literal[
    "arm",
    "freeze",
    "resume",
    "abort",
    "reset",
    "nothing",
    "busy",
    "after abort",
    "wrong mode",
    "armed first",
]
"""What a command does in a stage: a transition (``arm`` to ``reset``: its handler's own
checks may still refuse it), ``nothing`` (no event), or a refusal (``ignored``):
``busy`` (a run under way: abort first), ``after abort`` (reset first), ``wrong mode``,
``armed first`` (a freeze or resume is armed: it applies first)."""

COMMANDS = ("start", "freeze", "resume", "abort", "reset", "admit", "handback")
"""Every command :class:`RunCommand` names, in the columns of :data:`COMMAND_RULES`."""

# fmt: off
_RULE_ROWS: dict[Stage, tuple[Outcome, Outcome, Outcome, Outcome, Outcome, Outcome]] = {
    #             start          freeze         resume         abort      reset      admit
    "waiting":  ("arm",         "wrong mode",  "wrong mode",  "abort",   "nothing", "nothing"),
    "armed":    ("arm",         "wrong mode",  "wrong mode",  "abort",   "reset",   "nothing"),
    "running":  ("busy",        "freeze",      "wrong mode",  "abort",   "busy",    "nothing"),
    "freezing": ("busy",        "freeze",      "armed first", "abort",   "busy",    "nothing"),
    "frozen":   ("busy",        "wrong mode",  "resume",      "abort",   "busy",    "nothing"),
    "resuming": ("busy",        "armed first", "resume",      "abort",   "busy",    "nothing"),
    "done":     ("arm",         "wrong mode",  "wrong mode",  "abort",   "reset",   "nothing"),
    "aborted":  ("after abort", "after abort", "after abort", "nothing", "reset",   "nothing"),
}
# fmt: on

COMMAND_RULES: dict[tuple[Stage, str], Outcome] = {
    (mode, command): outcome
    for mode, row in _RULE_ROWS.items()
    # handback, like admit: nothing in every stage (rule 7)
    for command, outcome in zip(COMMANDS, (*row, "nothing"), strict=True)
}
"""(stage, command) to what the command does in that stage: rules 1 to 5 and 7 of the
module's docstring, without their instants."""

_REFUSALS: dict[Outcome, str] = {
    "busy": "{command} while {mode}: abort first",
    "after abort": "{command} after abort: fedlab ctl reset first",
    "wrong mode": "{command} while {mode}",
    "armed first": "{command} while {mode}: the armed one applies first (or abort)",
}
"""The detail of an ``ignored`` event, for each outcome that refuses."""


def rule(mode: Stage, command: str) -> Outcome:
    """What ``command`` does in ``mode`` (a stage): its :data:`COMMAND_RULES` entry. A
    command the table does not name is refused as one in the wrong mode, and after an
    abort as every command but abort and reset."""
    return COMMAND_RULES.get((mode, command), "after abort" if mode == "aborted" else "wrong mode")


def _refusal(outcome: Outcome, command: str, mode: Stage, t_sim: float | None) -> Event:
    return Event("ignored", t_sim, _REFUSALS[outcome].format(command=command, mode=mode))


# ------------------------------------------------------------------ checks of time

Check = Callable[["RunState", RunCommand, float | None], Event | None]
"""A check of a command against the state and the reference time of its receipt: the
``ignored`` event that refuses it, or None."""


def _sent_long_ago(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rule 6: a command on receipt (no ``at``) whose ``issued_at`` is more than
    ``LATE_START`` past waited behind a cut link; acted on now, it would set platforms
    moving when no one chose."""
    issued = getattr(cmd, "issued_at", None)
    if cmd.at is None and issued is not None and t_sim is not None and t_sim - issued > LATE_START:
        return Event("ignored", t_sim, f"{cmd.command} issued {t_sim - issued:.1f} s ago")
    return None


def _unstamped(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rule 6: ctl stamps every resume; one that says neither when to act nor when it
    was sent (an older ctl, a script) may have waited any time, and sets platforms
    moving."""
    if cmd.at is None and getattr(cmd, "issued_at", None) is None:
        return Event("ignored", t_sim, f"{cmd.command} without at or issued_at: not sent by ctl")
    return None


def _instant_passed(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rules 4 and 5: a start or resume whose ``at`` is more than ``LATE_START`` past.
    Acted on at that instant it would jump the run's clock, and begun part-way a run is
    not the one the others fly (ctl aborts a start not every participant confirmed
    before it: ask again)."""
    if cmd.at is not None and t_sim is not None and t_sim - cmd.at > LATE_START:
        return Event("ignored", t_sim, f"{cmd.command} instant passed {t_sim - cmd.at:.1f} s ago")
    return None


def _before_the_freeze(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rule 5: a resume whose ``at`` is before the freeze's instant (armed or applied)
    would resume a run before it froze: the agents that took the freeze first and those
    that took the resume first would not agree on the run's clock."""
    freeze = state.freeze_at
    if cmd.at is not None and freeze is not None and cmd.at < freeze:
        return Event(
            "ignored", t_sim, f"resume at {cmd.at:.3f} s, before the freeze at {freeze:.3f} s"
        )
    return None


def _unsynchronized(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rule 4: a start now needs the present reference time."""
    if cmd.at is None and t_sim is None:
        return Event("ignored", None, "start now, but not synchronized yet")
    return None


def _endless(state: RunState, cmd: RunCommand, t_sim: float | None) -> Event | None:
    """Rule 4: a run must end. Without a duration, from the start or the run state's
    default, it would fly until someone aborts it (ctl gives one)."""
    if getattr(cmd, "duration", None) is None and state.default_duration is None:
        return Event("ignored", t_sim, "start without a duration: a run must end")
    return None


_ON_RECEIPT: tuple[Check, ...] = (_sent_long_ago,)

TIMING_CHECKS: dict[str, tuple[Check, ...]] = {
    "start": _ON_RECEIPT,
    "resume": (_sent_long_ago, _unstamped, _instant_passed, _before_the_freeze),
    "freeze": (),  # a freeze late is a freeze now: it sets nothing moving
    "abort": (),
    "reset": (),
    "admit": (),  # nothing to a run state (rule 7)
    "handback": (),  # likewise
}
"""The checks a command passes, in this order, before its rule in :data:`COMMAND_RULES`
applies (not after an abort: rule 3 answers first). A command not named here is
checked as one on receipt."""

START_CHECKS: tuple[Check, ...] = (_unsynchronized, _instant_passed, _endless)
"""The checks a start passes, in this order, once its mode lets it arm."""


def _first_refusal(
    checks: tuple[Check, ...], state: RunState, cmd: RunCommand, t_sim: float | None
) -> Event | None:
    for check in checks:
        refused = check(state, cmd, t_sim)
        if refused is not None:
            return refused
    return None


def _instant(cmd: RunCommand, t_sim: float | None) -> float | None:
    """When a freeze or resume acts: at its ``at``, and at the present without an
    ``at``, without the present, or with an ``at`` more than ``LATE_START`` past (a
    freeze that late would rewind the run's clock, the leader slewing back to an old
    heading; refused, it would leave the platforms flying). An ``at`` to come is armed."""
    if cmd.at is None or t_sim is None or t_sim - cmd.at > LATE_START:
        return t_sim
    return cmd.at


def _lateness(cmd: RunCommand, t_sim: float | None) -> str:
    """What a freeze applied on receipt says of its instant: how late it came."""
    if cmd.at is None or t_sim is None or t_sim <= cmd.at:
        return ""
    if t_sim - cmd.at > LATE_START:
        return f"late: its instant passed {t_sim - cmd.at:.3f} s ago; frozen now"
    return f"late: received {t_sim - cmd.at:.3f} s after its instant"


class RunState:
    """The run mode, its start, frozen time, name and duration; ``duration``: a run's
    duration when its start gives none (an experiment's, known to the agent)."""

    def __init__(self, autostart: bool = False, duration: float | None = None):
        self.default_duration = duration
        self.mode: Mode = "waiting"
        self.start_at: float | None = None
        self.frozen_at: float | None = None
        self.resumed_at: float | None = None  # the reference time the run last resumed
        self.frozen_total = 0.0
        self.run_id: str | None = None
        self.duration: float | None = duration
        self.last_t_sim: float | None = None  # the reference time of the last update
        self.autostart = autostart
        # A freeze or resume announced for an instant to come: (command, reference time).
        self.armed: tuple[Literal["freeze", "resume"], float] | None = None
        self.last: Applied | None = None  # the run's last transition applied
        if autostart:
            self.mode = "armed"  # start_at set at the first update with a reference time

    @property
    def stage(self) -> Stage:
        """The mode, or ``freezing`` / ``resuming`` while a freeze / resume is armed."""
        if self.armed is None:
            return self.mode
        return "freezing" if self.armed[0] == "freeze" else "resuming"

    @property
    def freeze_at(self) -> float | None:
        """The freeze's instant, armed or applied (frozen); None otherwise."""
        if self.armed is not None and self.armed[0] == "freeze":
            return self.armed[1]
        return self.frozen_at if self.mode == "frozen" else None

    @property
    def due(self) -> float | None:
        """The reference time of the next transition a command armed (a start, a freeze,
        a resume), None if none is armed (an autostart's has no instant)."""
        if self.armed is not None:
            return self.armed[1]
        return self.start_at if self.mode == "armed" else None

    def command(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Apply a command received when the reference time was ``t_sim``: its checks of
        time (:data:`TIMING_CHECKS`), then its rule for the present stage
        (:data:`COMMAND_RULES`)."""
        outcome = rule(self.stage, cmd.command)
        if outcome != "after abort":
            checks = TIMING_CHECKS.get(cmd.command, _ON_RECEIPT)
            refused = _first_refusal(checks, self, cmd, t_sim)
            if refused is not None:
                return [refused]
        if outcome == "nothing":
            return []
        if outcome in _REFUSALS:
            return [_refusal(outcome, cmd.command, self.stage, t_sim)]
        return self._noted(self._TRANSITIONS[outcome](self, cmd, t_sim))

    def _arm(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Start: arm at ``at``, or now; it names the run and may give its duration."""
        refused = _first_refusal(START_CHECKS, self, cmd, t_sim)
        if refused is not None:
            return [refused]
        duration = getattr(cmd, "duration", None)
        self.mode, self.start_at = "armed", cmd.at if cmd.at is not None else t_sim
        self.frozen_total, self.frozen_at, self.autostart = 0.0, None, False
        self.resumed_at, self.armed, self.last = None, None, None
        self.run_id = getattr(cmd, "run_id", None)
        self.duration = self.default_duration if duration is None else duration
        return [Event("armed", self.start_at), *self.update(t_sim)]

    def _freeze(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Freeze a running run at an instant of its own (not before its start nor its
        last resume: that would rewind the run's clock); armed if it is to come, and
        then only if no freeze is armed for an earlier one."""
        at = _instant(cmd, t_sim)
        floor = max((t for t in (self.start_at, self.resumed_at) if t is not None), default=None)
        if at is not None and floor is not None:
            at = max(at, floor)
        if at is None:
            # No reference time now (its link contested, say): frozen at the last one
            # known, not left running while the others freeze.
            at = self.last_t_sim if self.last_t_sim is not None else self.start_at
        if at is None:
            return [_refusal("wrong mode", cmd.command, self.stage, t_sim)]
        earlier = self._earlier_armed("freeze", at, t_sim)
        if earlier is not None:
            return [earlier]
        if t_sim is not None and at > t_sim:
            self.armed = ("freeze", at)
            return [Event("freezing", at)]
        return self._apply_freeze(at, _lateness(cmd, t_sim))

    def _resume(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Resume a frozen run (the time frozen is not run time); armed if its instant
        is to come, and then only if no resume is armed for an earlier one."""
        at = _instant(cmd, t_sim)
        if at is None:
            return [_refusal("wrong mode", cmd.command, self.stage, t_sim)]
        assert self.frozen_at is not None  # set by the freeze
        at = max(at, self.frozen_at)  # no run time is made up before the freeze
        earlier = self._earlier_armed("resume", at, t_sim)
        if earlier is not None:
            return [earlier]
        if t_sim is not None and at > t_sim:
            self.armed = ("resume", at)
            return [Event("resuming", at)]
        return self._apply_resume(at)

    def _earlier_armed(self, command: str, at: float, t_sim: float | None) -> Event | None:
        """A second freeze (resume) while one is armed: the earlier instant is kept, so
        every agent keeps the same one whatever order the two arrive in."""
        if self.armed is None or at < self.armed[1]:
            return None
        armed = self.armed[1]
        return Event("ignored", t_sim, f"{command} at {at:.3f} s: one is armed for {armed:.3f} s")

    def _apply_freeze(self, at: float, detail: str = "") -> list[Event]:
        self.mode, self.frozen_at, self.armed = "frozen", at, None
        return [Event("frozen", at, detail)]

    def _apply_resume(self, at: float) -> list[Event]:
        assert self.frozen_at is not None
        self.frozen_total += max(0.0, at - self.frozen_at)
        self.mode, self.frozen_at, self.resumed_at, self.armed = "running", None, at, None
        return [Event("resumed", at)]

    def _abort(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Abort, holding the run time where it is: at the abort while running, at the
        freeze or the end while frozen or done, none before the start. A freeze or resume
        armed is dropped with the run."""
        if self.mode == "running":
            self.frozen_at = t_sim
        elif self.mode in ("waiting", "armed"):
            self.frozen_at = None
        self.mode, self.armed = "aborted", None
        return [Event("aborted", t_sim)]

    def _reset(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Back to waiting for a start (an operator's explicit act)."""
        self.mode, self.start_at, self.frozen_at = "waiting", None, None
        self.autostart, self.armed, self.last = False, None, None
        return [Event("reset", t_sim)]

    def rejoin(
        self,
        run_id: str,
        start_at: float,
        frozen_total: float,
        duration: float,
        t_sim: float | None,
    ) -> list[Event]:
        """Join a run under way at reference time ``t_sim``: from ``waiting`` only, with a
        run that has begun and not ended, ``running`` at once on the run's clock (its
        start instant and time frozen); ``ignored`` otherwise."""
        if self.mode != "waiting":
            return [Event("ignored", t_sim, f"rejoin while {self.mode}")]
        if t_sim is None:
            return [Event("ignored", None, "rejoin, but not synchronized yet")]
        run_time = t_sim - start_at - frozen_total
        if not 0.0 <= run_time < duration:
            return [Event("ignored", t_sim, f"rejoin at run time {run_time:.3f} s: no run then")]
        self.mode, self.start_at, self.frozen_total = "running", start_at, frozen_total
        self.frozen_at, self.resumed_at, self.armed, self.autostart = None, None, None, False
        self.run_id, self.duration, self.last_t_sim = run_id, duration, t_sim
        return self._noted([Event("rejoined", t_sim, f"at run time {run_time:.3f} s")])

    _TRANSITIONS: ClassVar[
        dict[Outcome, Callable[[RunState, RunCommand, float | None], list[Event]]]
    ] = {
        "arm": _arm,
        "freeze": _freeze,
        "resume": _resume,
        "abort": _abort,
        "reset": _reset,
    }
    """The handler of each outcome that is a transition."""

    def update(self, t_sim: float | None) -> list[Event]:
        """Advance time: an armed run starts once the reference time reaches its start,
        an armed freeze or resume applies once it reaches its instant, a running run is
        done once its run time reaches its duration."""
        if t_sim is None:
            return []
        self.last_t_sim = t_sim
        events = []
        if self.mode == "armed" and self.autostart and self.start_at is None:
            self.start_at = t_sim
        start = self.start_at
        if self.mode == "armed" and start is not None and t_sim >= start:
            self.mode = "running"
            events.append(Event("started", t_sim))
        if self.armed is not None and t_sim >= self.armed[1]:
            events += self._due_now()
        if self.mode == "running" and self.duration is not None:
            run_time = self.run_time(t_sim)
            if run_time is not None and run_time >= self.duration:
                assert start is not None
                self.mode, self.armed = "done", None
                self.frozen_at = start + self.frozen_total + self.duration  # run time held
                events.append(Event("done", self.frozen_at))
        return self._noted(events)

    def _due_now(self) -> list[Event]:
        """The armed freeze or resume, its instant reached: applied at that instant. A
        freeze at or after the run's end is dropped: the run is done first."""
        assert self.armed is not None
        command, at = self.armed
        if command == "resume":
            return self._apply_resume(at)
        start, duration = self.start_at, self.duration
        if (
            start is not None
            and duration is not None
            and at >= start + self.frozen_total + duration
        ):
            self.armed = None
            return []
        return self._apply_freeze(at)

    def _noted(self, events: list[Event]) -> list[Event]:
        """``events``, the last transition among them kept as :attr:`last`."""
        applied = [e for e in events if e.kind in APPLIED_KINDS]
        if applied:
            event = applied[-1]
            at = self.start_at if event.kind == "started" else event.t_sim
            run_time = 0.0 if event.kind == "started" else self.run_time(at)
            self.last = Applied(event.kind, at, run_time, event.detail)
        return events

    def run_time(self, t_sim: float | None) -> float | None:
        """Seconds of experiment so far (None before the start or without sync); held at
        the duration once done, and at the abort's run time once aborted. Never past the
        duration: ``t_sim`` read between the end's instant and the update that applies it
        (a status built then) is still at most the end."""
        if t_sim is None or self.start_at is None or self.mode in ("waiting", "armed"):
            return None
        if self.mode in ("frozen", "done", "aborted"):
            if self.frozen_at is None:
                return None
            return max(0.0, self.frozen_at - self.start_at - self.frozen_total)
        run_time = max(0.0, t_sim - self.start_at - self.frozen_total)
        return run_time if self.duration is None else min(run_time, self.duration)

    def fraction(self, t_sim: float | None) -> float | None:
        """Share of the duration flown (0 to 1), None without a duration or a run."""
        run_time = self.run_time(t_sim)
        if run_time is None or not self.duration:
            return None
        return min(1.0, run_time / self.duration)

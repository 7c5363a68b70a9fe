"""Run modes of an experiment, free of I/O: commands in, mode and run time out.

::

    waiting --start(at)--> armed --t_sim >= at--> running --freeze--> frozen
      ^  ^                  |  ^                   |   ^                 |
      |  |                  |  +--start (re-arm)   |   +-----resume------+
      |  +------reset-------+                      |
      |                                  run_time >= duration
      |                                            v
      +------------reset----------------------- done --start--> armed
    any mode --abort--> aborted --reset--> waiting

The rules, in the order :meth:`RunState.command` applies them (which commands reach
it at all is decided first by :class:`federation.core.commands.CommandGate`):

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
   later than the present, not earlier than the run's start or the freeze) or the
   present; a resume's ``at`` more than ``LATE_START`` past is ``ignored``, as a
   start's is, and a freeze's makes it freeze at the present; anything else is
   ``ignored``.
6. A start or resume without ``at`` acts on receipt, unless its ``issued_at`` (the
   reference time it was sent) is more than ``LATE_START`` past: ``ignored`` (it waited
   behind a cut link; acted on now, it would set platforms moving when no one chose).
   A resume with neither is ``ignored`` (ctl stamps every resume). A freeze acts on
   receipt however late, and without the reference time at the last one known.

:meth:`RunState.update` makes the transitions no command makes: armed to running
once the reference time reaches the start, running to done once the run time
reaches the duration.

``run_time`` is the experiment's clock: reference time since the start, less the
time spent frozen. The leader's maneuver is a function of it.

``autostart`` (a lone agent, no ``ctl start``): the run starts at the first
update with a reference time, so the run time counts from when the agent is
ready, not from its clock's zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, get_args

__all__ = ["HOLD_MODES", "MOVING_MODES", "Event", "Mode", "RunCommand", "RunState"]

Mode = Literal["waiting", "armed", "running", "frozen", "done", "aborted"]

HOLD_MODES: frozenset[str] = frozenset({"waiting", "armed", "done", "aborted"})
"""Modes in which every valve stays closed: a platform moves only in a run under way
(running, or frozen: holding its point). Before its start it waits, held: a real
platform had fired its valves from the moment its agent started, steering to heading
0 or after its leader, before any operator's start."""
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

    kind: Literal["armed", "started", "frozen", "resumed", "done", "aborted", "reset", "ignored"]
    t_sim: float | None  # reference time the event refers to (s)
    detail: str = ""


class RunState:
    """The run mode, its start, frozen time, name and duration; ``duration``: a run's
    duration when its start gives none (an experiment's, known to the agent)."""

    def __init__(self, autostart: bool = False, duration: float | None = None):
        self.default_duration = duration
        self.mode: Mode = "waiting"
        self.start_at: float | None = None
        self.frozen_at: float | None = None
        self.frozen_total = 0.0
        self.run_id: str | None = None
        self.duration: float | None = duration
        self.last_t_sim: float | None = None  # the reference time of the last update
        self.autostart = autostart
        if autostart:
            self.mode = "armed"  # start_at set at the first update with a reference time

    def command(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Apply a command received when the reference time was ``t_sim``."""
        kind = cmd.command
        if kind == "abort":
            if self.mode == "aborted":
                return []
            if self.mode == "running":
                self.frozen_at = t_sim  # run time held at the abort
            elif self.mode in ("waiting", "armed"):
                self.frozen_at = None  # no run time: it never started
            self.mode = "aborted"
            return [Event("aborted", t_sim)]
        if kind == "reset":
            if self.mode in ("aborted", "done", "armed"):
                self.mode, self.start_at, self.frozen_at = "waiting", None, None
                self.autostart = False
                return [Event("reset", t_sim)]
            if self.mode == "waiting":
                return []
            return [Event("ignored", t_sim, f"reset while {self.mode}: abort first")]
        if self.mode == "aborted":
            return [Event("ignored", t_sim, f"{kind} after abort: fedlab ctl reset first")]
        issued = getattr(cmd, "issued_at", None)
        if (
            kind != "freeze"  # a freeze late is a freeze now: it sets nothing moving
            and cmd.at is None
            and issued is not None
            and t_sim is not None
            and t_sim - issued > LATE_START
        ):
            # On receipt, but received long after it was sent (behind a cut link).
            return [Event("ignored", t_sim, f"{kind} issued {t_sim - issued:.1f} s ago")]
        if kind == "start":
            if self.mode in ("running", "frozen"):
                return [Event("ignored", t_sim, f"start while {self.mode}: abort first")]
            if cmd.at is None and t_sim is None:
                return [Event("ignored", None, "start now, but not synchronized yet")]
            if cmd.at is not None and t_sim is not None and t_sim - cmd.at > LATE_START:
                # Begun part-way, the run would not be the one the others fly: ctl aborts
                # a start not every participant confirmed before it; ask again.
                return [Event("ignored", t_sim, f"start instant passed {t_sim - cmd.at:.1f} s ago")]
            duration = getattr(cmd, "duration", None)
            if duration is None and self.default_duration is None:
                # A run that never ends flies until someone aborts it (ctl gives one).
                return [Event("ignored", t_sim, "start without a duration: a run must end")]
            self.mode, self.start_at = "armed", cmd.at if cmd.at is not None else t_sim
            self.frozen_total, self.frozen_at, self.autostart = 0.0, None, False
            self.run_id = getattr(cmd, "run_id", None)
            self.duration = self.default_duration if duration is None else duration
            return [Event("armed", self.start_at), *self.update(t_sim)]
        if kind == "resume" and cmd.at is None and issued is None:
            # ctl stamps every resume: one that does not say when it was sent may have
            # waited any time (an older ctl, a script), and sets platforms moving.
            return [Event("ignored", t_sim, "resume without at or issued_at: not sent by ctl")]
        late = cmd.at is not None and t_sim is not None and t_sim - cmd.at > LATE_START
        if late and kind == "resume":
            # Acted on at a past instant, a resume had jumped the run's clock (and set the
            # platform moving at a time no one chose now): as late as a start.
            assert cmd.at is not None and t_sim is not None
            return [Event("ignored", t_sim, f"{kind} instant passed {t_sim - cmd.at:.1f} s ago")]
        # A freeze at a long past instant had rewound the run's clock (the leader slewed
        # back to an old heading): late, it freezes now instead (ignored, it had left the
        # platforms flying).
        at = t_sim if cmd.at is None or t_sim is None or late else min(cmd.at, t_sim)
        if kind == "freeze" and at is not None and self.start_at is not None:
            at = max(at, self.start_at)  # an instant before the run is not one of its own
        if kind == "resume" and at is not None and self.frozen_at is not None:
            at = max(at, self.frozen_at)  # no run time is made up before the freeze
        if kind == "freeze" and self.mode == "running" and at is None:
            # No reference time now (its link contested, say): frozen at the last one
            # known, not left running while the others freeze.
            at = self.last_t_sim if self.last_t_sim is not None else self.start_at
        if kind == "freeze" and self.mode == "running" and at is not None:
            self.mode, self.frozen_at = "frozen", at
            return [Event("frozen", at)]
        if kind == "resume" and self.mode == "frozen" and at is not None:
            assert self.frozen_at is not None
            self.frozen_total += max(0.0, at - self.frozen_at)
            self.mode, self.frozen_at = "running", None
            return [Event("resumed", at)]
        return [Event("ignored", t_sim, f"{kind} while {self.mode}")]

    def update(self, t_sim: float | None) -> list[Event]:
        """Advance time: an armed run starts once the reference time reaches its start;
        a running one is done once its run time reaches its duration."""
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
        if self.mode == "running" and self.duration is not None:
            run_time = self.run_time(t_sim)
            if run_time is not None and run_time >= self.duration:
                assert start is not None
                self.mode = "done"
                self.frozen_at = start + self.frozen_total + self.duration  # run time held
                events.append(Event("done", self.frozen_at))
        return events

    def run_time(self, t_sim: float | None) -> float | None:
        """Seconds of experiment so far (None before the start or without sync); held at
        the duration once done, and at the abort's run time once aborted."""
        if t_sim is None or self.start_at is None or self.mode in ("waiting", "armed"):
            return None
        if self.mode in ("frozen", "done", "aborted"):
            if self.frozen_at is None:
                return None
            return max(0.0, self.frozen_at - self.start_at - self.frozen_total)
        return max(0.0, t_sim - self.start_at - self.frozen_total)

    def fraction(self, t_sim: float | None) -> float | None:
        """Share of the duration flown (0 to 1), None without a duration or a run."""
        run_time = self.run_time(t_sim)
        if run_time is None or not self.duration:
            return None
        return min(1.0, run_time / self.duration)

"""Run modes of an experiment, free of I/O: commands in, mode and run time out.

::

    waiting --start(at)--> armed --t_sim >= at--> running --freeze--> frozen
                             ^                       ^                  |
                             |                       +-----resume-------+
                             +-- start(at) from armed, running or frozen (re-arm)
    any mode --abort--> aborted   (safe hold: all valves closed; final)

The rules, in the order :meth:`RunState.command` applies them:

1. A command whose ``seq`` is not above every seq seen is a repeat: no event.
2. ``abort`` aborts from any mode, aborted included.
3. After an abort every other command is ``ignored``.
4. ``start`` arms (``at``, or the present reference time without one) and starts
   at once if that time has come; without ``at`` and unsynchronized it is ``ignored``.
5. ``freeze`` only while running, ``resume`` only while frozen, each at ``at`` or
   the present; anything else is ``ignored``.

:meth:`RunState.update` is the one transition not made by a command: armed to
running once the reference time reaches the start.

``run_time`` is the experiment's clock: reference time since the start, less the
time spent frozen. The leader's maneuver is a function of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

__all__ = ["Event", "Mode", "RunCommand", "RunState"]

Mode = Literal["waiting", "armed", "running", "frozen", "aborted"]


class RunCommand(Protocol):
    """What the run state reads of a command (:class:`schemas.messages.Command` is one)."""

    @property
    def command(self) -> str:
        """``start``, ``freeze``, ``resume`` or ``abort``."""

    @property
    def seq(self) -> int:
        """The command's number: a repeat of a seen one is ignored."""

    @property
    def at(self) -> float | None:
        """Reference time (s) at which to act; None: on receipt."""


@dataclass(frozen=True)
class Event:
    """What a transition (or a refused command) did, for the log and the recording."""

    kind: Literal["armed", "started", "frozen", "resumed", "aborted", "ignored"]
    t_sim: float | None  # reference time the event refers to (s)
    detail: str = ""


class RunState:
    """``autostart``: the run starts at reference time 0 with no command (a lone agent)."""

    def __init__(self, autostart: bool = False):
        self.mode: Mode = "waiting"
        self.start_at: float | None = None
        self.frozen_at: float | None = None
        self.frozen_total = 0.0
        self.last_seq = -1
        if autostart:
            self.mode, self.start_at = "armed", 0.0

    def command(self, cmd: RunCommand, t_sim: float | None) -> list[Event]:
        """Apply a command received when the reference time was ``t_sim``."""
        if cmd.seq <= self.last_seq:
            return []
        self.last_seq = cmd.seq
        if cmd.command == "abort":
            self.mode = "aborted"
            return [Event("aborted", t_sim)]
        if self.mode == "aborted":
            return [Event("ignored", t_sim, f"{cmd.command} after abort")]
        if cmd.command == "start":
            if cmd.at is None and t_sim is None:
                return [Event("ignored", None, "start now, but not synchronized yet")]
            self.mode, self.start_at = "armed", cmd.at if cmd.at is not None else t_sim
            self.frozen_total, self.frozen_at = 0.0, None
            return [Event("armed", self.start_at), *self.update(t_sim)]
        at = cmd.at if cmd.at is not None else t_sim
        if cmd.command == "freeze" and self.mode == "running" and at is not None:
            self.mode, self.frozen_at = "frozen", at
            return [Event("frozen", at)]
        if cmd.command == "resume" and self.mode == "frozen" and at is not None:
            assert self.frozen_at is not None
            self.frozen_total += max(0.0, at - self.frozen_at)
            self.mode, self.frozen_at = "running", None
            return [Event("resumed", at)]
        return [Event("ignored", t_sim, f"{cmd.command} while {self.mode}")]

    def update(self, t_sim: float | None) -> list[Event]:
        """Advance time: an armed run starts once the reference time reaches its start."""
        start = self.start_at
        if self.mode == "armed" and start is not None and t_sim is not None and t_sim >= start:
            self.mode = "running"
            return [Event("started", t_sim)]
        return []

    def run_time(self, t_sim: float | None) -> float | None:
        """Seconds of experiment so far (None before the start or without sync)."""
        if t_sim is None or self.start_at is None or self.mode in ("waiting", "armed"):
            return None
        end = self.frozen_at if self.mode == "frozen" and self.frozen_at is not None else t_sim
        return max(0.0, end - self.start_at - self.frozen_total)

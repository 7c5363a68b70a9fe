"""Run modes of an experiment, free of I/O: commands in, mode and run time out.

::

    waiting --start(at)--> armed --t_sim >= at--> running --freeze--> frozen
                                                     ^                  |
                                                     +-----resume-------+
    any mode --abort--> aborted   (safe hold: all valves closed; final)

``run_time`` is the experiment's clock: reference time since the start, less the
time spent frozen. The leader's maneuver is a function of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from schemas.messages import Command

__all__ = ["Event", "Mode", "RunState"]

Mode = Literal["waiting", "armed", "running", "frozen", "aborted"]


@dataclass(frozen=True)
class Event:
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

    @property
    def held(self) -> bool:
        """Safe hold: the platform must keep every valve closed."""
        return self.mode == "aborted"

    def command(self, cmd: Command, t_sim: float | None) -> list[Event]:
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

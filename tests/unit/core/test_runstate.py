"""Run modes (federation/core/runstate.py), one transition at a time.

Every edge of the state diagram in the module's docstring, then every command it
ignores. Commands are plain records: the run state reads only ``command``,
``seq`` and ``at`` (:class:`schemas.messages.Command` has those and more).
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from federation.core.runstate import Event, Mode, RunCommand, RunState
from schemas.messages import Command


@dataclass(frozen=True)
class Cmd:
    command: str
    seq: int
    at: float | None = None


def in_mode(mode: Mode) -> RunState:
    """A run state brought to ``mode`` by commands (seqs 0 to 2); run started at 5 s."""
    state = RunState()
    if mode == "waiting":
        return state
    state.command(Cmd("start", 0, at=5.0), t_sim=1.0)
    if mode == "armed":
        return state
    state.update(5.0)
    if mode == "running":
        return state
    if mode == "frozen":
        state.command(Cmd("freeze", 1, at=8.0), t_sim=8.0)
        return state
    state.command(Cmd("abort", 2), t_sim=9.0)
    return state


@pytest.mark.parametrize("mode", ["waiting", "armed", "running", "frozen", "aborted"])
def test_in_mode_reaches_each_mode(mode: Mode) -> None:
    assert in_mode(mode).mode == mode


# ------------------------------------------------------------------ the edges


def test_waiting_start_at_arms() -> None:
    state = RunState()
    assert state.command(Cmd("start", 0, at=5.0), t_sim=1.0) == [Event("armed", 5.0)]
    assert (state.mode, state.start_at) == ("armed", 5.0)
    assert state.run_time(4.0) is None


def test_armed_starts_when_reference_time_reaches_the_start() -> None:
    state = in_mode("armed")
    assert state.update(4.999) == []
    assert state.update(None) == []  # not synchronized: no time, no start
    assert state.mode == "armed"
    assert (state.update(5.0), state.mode) == ([Event("started", 5.0)], "running")
    assert state.update(6.0) == []  # started once
    assert state.run_time(7.5) == pytest.approx(2.5)


def test_a_start_whose_time_has_come_arms_and_starts_at_once() -> None:
    state = RunState()
    events = state.command(Cmd("start", 0, at=5.0), t_sim=6.0)
    assert events == [Event("armed", 5.0), Event("started", 6.0)]
    assert state.mode == "running" and state.run_time(6.0) == pytest.approx(1.0)


def test_a_start_without_at_starts_now() -> None:
    state = RunState()
    assert state.command(Cmd("start", 0), t_sim=3.0) == [Event("armed", 3.0), Event("started", 3.0)]
    assert state.start_at == 3.0 and state.mode == "running"


def test_running_freeze_freezes_and_run_time_stops() -> None:
    state = in_mode("running")
    assert state.command(Cmd("freeze", 1, at=8.0), t_sim=7.9) == [Event("frozen", 8.0)]
    assert (state.mode, state.frozen_at) == ("frozen", 8.0)
    assert state.run_time(20.0) == pytest.approx(3.0)  # held at the freeze


def test_a_freeze_without_at_freezes_now() -> None:
    state = in_mode("running")
    assert state.command(Cmd("freeze", 1), t_sim=7.0) == [Event("frozen", 7.0)]
    assert state.frozen_at == 7.0


def test_frozen_resume_runs_again_less_the_time_frozen() -> None:
    state = in_mode("frozen")  # started at 5, frozen at 8
    assert state.command(Cmd("resume", 2, at=10.0), t_sim=9.9) == [Event("resumed", 10.0)]
    assert state.mode == "running" and state.frozen_at is None
    assert state.frozen_total == pytest.approx(2.0)
    assert state.run_time(12.0) == pytest.approx(5.0)  # 7 s since the start, 2 s frozen


def test_a_resume_before_the_freeze_adds_no_frozen_time() -> None:
    state = in_mode("frozen")  # frozen at 8
    assert state.command(Cmd("resume", 2, at=7.0), t_sim=8.0) == [Event("resumed", 7.0)]
    assert state.frozen_total == 0.0


@pytest.mark.parametrize("mode", ["armed", "running", "frozen"])
def test_start_re_arms_from_armed_running_or_frozen(mode: Mode) -> None:
    state = in_mode(mode)
    assert state.command(Cmd("start", 10, at=30.0), t_sim=12.0) == [Event("armed", 30.0)]
    assert (state.mode, state.start_at) == ("armed", 30.0)
    assert (state.frozen_total, state.frozen_at) == (0.0, None)  # a fresh run
    assert state.update(30.0) == [Event("started", 30.0)]
    assert state.run_time(31.0) == pytest.approx(1.0)


@pytest.mark.parametrize("mode", ["waiting", "armed", "running", "frozen", "aborted"])
def test_abort_from_any_mode_is_final(mode: Mode) -> None:
    state = in_mode(mode)
    assert state.command(Cmd("abort", 10), t_sim=9.5) == [Event("aborted", 9.5)]
    assert state.mode == "aborted"
    assert state.update(100.0) == []


def test_autostart_is_armed_for_reference_time_zero() -> None:
    state = RunState(autostart=True)
    assert (state.mode, state.start_at) == ("armed", 0.0)
    assert state.update(0.0) == [Event("started", 0.0)]


# ------------------------------------------------------------------ ignored commands


@pytest.mark.parametrize("seq", [0, 1])
def test_a_repeated_or_older_seq_does_nothing(seq: int) -> None:
    state = in_mode("frozen")  # seqs 0 and 1 seen
    assert state.command(Cmd("abort", seq), t_sim=9.0) == []
    assert state.command(Cmd("resume", seq, at=9.0), t_sim=9.0) == []
    assert state.mode == "frozen" and state.last_seq == 1


@pytest.mark.parametrize("command", ["start", "freeze", "resume"])
def test_after_an_abort_everything_but_abort_is_ignored(command: str) -> None:
    state = in_mode("aborted")
    assert state.command(Cmd(command, 10, at=20.0), t_sim=9.5) == [
        Event("ignored", 9.5, f"{command} after abort")
    ]
    assert state.mode == "aborted" and state.last_seq == 10


def test_start_now_unsynchronized_is_ignored() -> None:
    state = RunState()
    assert state.command(Cmd("start", 0), t_sim=None) == [
        Event("ignored", None, "start now, but not synchronized yet")
    ]
    assert state.mode == "waiting" and state.start_at is None


def test_start_at_a_time_needs_no_synchronization_to_arm() -> None:
    state = RunState()
    assert state.command(Cmd("start", 0, at=5.0), t_sim=None) == [Event("armed", 5.0)]


@pytest.mark.parametrize(
    ("mode", "command"),
    [
        ("waiting", "freeze"),
        ("armed", "freeze"),
        ("frozen", "freeze"),
        ("waiting", "resume"),
        ("armed", "resume"),
        ("running", "resume"),
    ],
)
def test_freeze_only_while_running_and_resume_only_while_frozen(mode: Mode, command: str) -> None:
    state = in_mode(mode)
    before = (state.mode, state.start_at, state.frozen_at, state.frozen_total)
    assert state.command(Cmd(command, 10, at=9.0), t_sim=8.5) == [
        Event("ignored", 8.5, f"{command} while {mode}")
    ]
    assert (state.mode, state.start_at, state.frozen_at, state.frozen_total) == before


@pytest.mark.parametrize(("mode", "command"), [("running", "freeze"), ("frozen", "resume")])
def test_freeze_or_resume_now_unsynchronized_is_ignored(mode: Mode, command: str) -> None:
    state = in_mode(mode)
    assert state.command(Cmd(command, 10), t_sim=None) == [
        Event("ignored", None, f"{command} while {mode}")
    ]
    assert state.mode == mode


# ------------------------------------------------------------------ run time


def test_run_time_is_none_before_the_start_or_without_time() -> None:
    assert RunState().run_time(5.0) is None
    assert in_mode("armed").run_time(6.0) is None  # armed: not started yet
    assert in_mode("running").run_time(None) is None
    assert in_mode("running").run_time(4.0) == 0.0  # never negative


def test_the_schema_command_is_a_run_command() -> None:
    command: RunCommand = Command(command="start", seq=0, at=5.0)
    state = RunState()
    assert state.command(command, t_sim=1.0) == [Event("armed", 5.0)]

"""Run modes (federation/core/runstate.py): the edges of its rules that mutation testing
showed no test held (docs/mutation.md): how late is too late, exactly; what an abort
holds in every mode; the share of the run flown."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

import pytest

from federation.core.runstate import LATE_START, Event, RunState, rule


@dataclass(frozen=True)
class Cmd:
    command: str
    at: float | None = None
    issued_at: float | None = None
    run_id: str | None = "run"
    duration: float | None = 10.0


def running(start: float = 5.0, duration: float = 10.0) -> RunState:
    state = RunState()
    state.command(Cmd("start", at=start, duration=duration), t_sim=start)
    assert state.mode == "running"
    return state


def frozen(at: float = 8.0) -> RunState:
    state = running()
    state.command(Cmd("freeze", at=at), t_sim=at)
    assert state.mode == "frozen"
    return state


# ------------------------------------------------------------------ how late is too late

NOW = 50.0
EDGE = NOW - LATE_START  # exactly LATE_START before NOW (both exact in binary)


def test_a_start_or_resume_sent_exactly_late_start_ago_still_acts() -> None:
    # Refused only when sent *more than* LATE_START ago (rule 6).
    start = RunState().command(Cmd("start", issued_at=EDGE), t_sim=NOW)
    assert start == [Event("armed", NOW), Event("started", NOW)]
    resume = frozen(at=8.0).command(Cmd("resume", issued_at=EDGE), t_sim=NOW)
    assert resume == [Event("resumed", NOW)]


def test_a_start_or_resume_exactly_late_start_past_its_instant_acts_at_it() -> None:
    # Rules 4 and 5: refused only when its instant is *more than* LATE_START past.
    start = RunState().command(Cmd("start", at=EDGE), t_sim=NOW)
    assert start == [Event("armed", EDGE), Event("started", NOW)]
    state = frozen(at=8.0)
    assert state.command(Cmd("resume", at=EDGE), t_sim=NOW) == [Event("resumed", EDGE)]
    assert state.frozen_total == EDGE - 8.0


def test_a_freeze_exactly_late_start_past_its_instant_freezes_at_it() -> None:
    # Rule 5: only a freeze *more than* LATE_START late freezes at the present.
    state = running(start=5.0)
    late = "late: received 1.000 s after its instant"
    assert state.command(Cmd("freeze", at=EDGE), t_sim=NOW) == [Event("frozen", EDGE, late)]
    assert state.run_time(NOW + 10.0) == EDGE - 5.0


@pytest.mark.parametrize("late", [10.0, 3600.0])
def test_a_start_or_resume_sent_long_ago_is_ignored_and_says_how_long(late: float) -> None:
    now = 2 * late
    (start,) = RunState().command(Cmd("start", issued_at=now - late), t_sim=now)
    assert start == Event("ignored", now, f"start issued {late:.1f} s ago")
    state = frozen()
    (resume,) = state.command(Cmd("resume", issued_at=now - late), t_sim=now)
    assert resume == Event("ignored", now, f"resume issued {late:.1f} s ago")
    assert state.mode == "frozen"


@pytest.mark.parametrize("late", [10.0, 3600.0])
def test_a_start_or_resume_whose_instant_is_long_past_is_ignored(late: float) -> None:
    now = 2 * late
    state = RunState()
    (start,) = state.command(Cmd("start", at=now - late), t_sim=now)
    assert start == Event("ignored", now, f"start instant passed {late:.1f} s ago")
    assert state.mode == "waiting"
    state = frozen()
    (resume,) = state.command(Cmd("resume", at=now - late), t_sim=now)
    assert resume == Event("ignored", now, f"resume instant passed {late:.1f} s ago")
    assert state.mode == "frozen"


@pytest.mark.parametrize("late", [10.0, 3600.0])
def test_a_freeze_whose_instant_is_long_past_freezes_now(late: float) -> None:
    now = 2 * late
    state = running()
    said = f"late: its instant passed {late:.3f} s ago; frozen now"
    assert state.command(Cmd("freeze", at=now - late), t_sim=now) == [Event("frozen", now, said)]


# ------------------------------------------------------------------ what an abort holds


def test_an_abort_while_frozen_holds_the_run_time_at_the_freeze() -> None:
    state = frozen(at=8.0)  # started at 5
    assert state.command(Cmd("abort"), t_sim=20.0) == [Event("aborted", 20.0)]
    assert state.run_time(30.0) == 3.0


def test_an_abort_when_done_holds_the_run_time_at_the_duration() -> None:
    state = running(start=5.0, duration=10.0)
    assert state.update(15.5) == [Event("done", 15.0)]
    state.command(Cmd("abort"), t_sim=20.0)
    assert (state.mode, state.run_time(30.0)) == ("aborted", 10.0)


@pytest.mark.parametrize("before", ["waiting", "armed", "autostart"])
def test_an_abort_before_the_start_leaves_no_run_time(before: str) -> None:
    # "none before the start": nothing to hold, no instant it is held at.
    state = RunState(autostart=before == "autostart", duration=10.0)
    if before == "armed":
        state.command(Cmd("start", at=30.0), t_sim=5.0)
    start_at = state.start_at
    state.command(Cmd("abort"), t_sim=6.0)
    assert state.mode == "aborted" and state.frozen_at is None
    assert state.update(40.0) == [] and state.start_at == start_at  # aborted: never starts
    assert state.run_time(40.0) is None and state.fraction(40.0) is None


def test_waiting_has_no_start_however_long_it_waits() -> None:
    # Only a start arms a run (and autostart, which starts armed): updates while waiting,
    # or aborted before any start, set no start.
    state = RunState(duration=10.0)
    assert state.update(5.0) == [] and state.update(50.0) == []
    assert (state.mode, state.start_at, state.run_time(60.0)) == ("waiting", None, None)
    state.command(Cmd("abort"), t_sim=60.0)
    assert state.update(70.0) == []
    assert (state.mode, state.start_at, state.run_time(80.0)) == ("aborted", None, None)


# ------------------------------------------------------------------ run time and its share


def test_an_event_is_a_record_no_one_rewrites() -> None:
    # What the log and the recording say a transition did stays what it did.
    (event,) = running().command(Cmd("freeze"), t_sim=7.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        event.t_sim = 0.0  # type: ignore[misc]


def test_frozen_again_the_run_time_held_leaves_out_every_freeze() -> None:
    state = frozen(at=8.0)  # started at 5
    state.command(Cmd("resume", at=10.0), t_sim=10.0)  # 2 s frozen
    state.command(Cmd("freeze", at=12.0), t_sim=12.0)
    assert state.run_time(30.0) == 5.0  # 3 s, then 2 s more


def test_done_the_run_time_is_held_at_the_duration_however_long_it_was_frozen() -> None:
    state = frozen(at=8.0)  # started at 5, 10 s long
    state.command(Cmd("resume", at=10.0), t_sim=10.0)
    assert state.update(17.0) == [Event("done", 17.0)]
    assert state.run_time(30.0) == 10.0 and state.fraction(30.0) == 1.0


def test_the_rule_of_a_mode_read_back_as_text_is_the_same() -> None:
    # A mode as the status or a recording carries it: equal text, not the same object.
    for mode in ("aborted", "waiting"):
        text = json.loads(json.dumps(mode))
        for command in ("start", "launch"):
            assert rule(text, command) == rule(mode, command)  # type: ignore[arg-type]


def test_run_time_is_never_negative_frozen_before_the_last_resume() -> None:
    # Frozen at its start, resumed 4 s later, frozen again with an instant 0.5 s before
    # the resume: the run time is held at no less than 0.
    state = running(start=5.0)
    state.command(Cmd("freeze", at=5.0), t_sim=5.0)
    state.command(Cmd("resume", at=9.0), t_sim=9.0)
    state.command(Cmd("freeze", at=8.5), t_sim=9.0)
    run_time = state.run_time(20.0)
    assert run_time is not None and run_time >= 0.0


def test_the_share_flown_is_none_without_a_run_or_a_duration() -> None:
    assert RunState(duration=10.0).fraction(5.0) is None  # waiting
    state = RunState()
    state.command(Cmd("start", at=30.0), t_sim=5.0)
    assert state.fraction(40.0) is None  # armed: no run yet
    endless = RunState(autostart=True)  # a lone agent given no duration
    endless.update(1.0)
    assert endless.mode == "running" and endless.run_time(3.0) == 2.0
    assert endless.fraction(3.0) is None
    assert endless.update(1e6) == [] and endless.mode == "running"  # never done


def test_the_share_flown_is_at_most_one_even_asked_past_the_end() -> None:
    # Asked at a time past the run's end before an update has ended it.
    state = running(start=5.0, duration=10.0)
    assert state.fraction(10.0) == 0.5
    assert state.fraction(40.0) == 1.0
    assert state.mode == "running"

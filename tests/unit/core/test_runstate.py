"""Run modes (federation/core/runstate.py), one transition at a time.

Every edge of the state diagram in the module's docstring, then every command it
ignores. Commands are plain records: the run state reads ``command``, ``at``,
``run_id`` and ``duration`` (:class:`schemas.messages.Command` has those and
more); which commands reach it is the command gate's business (test_commands.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import get_args

import pytest

from federation.core.runstate import (
    COMMAND_RULES,
    COMMANDS,
    TIMING_CHECKS,
    Applied,
    Event,
    Mode,
    Outcome,
    RunCommand,
    RunState,
    Stage,
    rule,
)
from schemas.messages import Command


@dataclass(frozen=True)
class Cmd:
    command: str
    seq: int = 0
    at: float | None = None
    run_id: str | None = "run"
    duration: float | None = 1000.0  # a run must end (rule 4)
    issued_at: float | None = None


def in_mode(mode: Stage) -> RunState:
    """A run state brought to ``mode`` (a stage) by commands (seqs 0 to 2); run started
    at 5 s; ``freezing``: a freeze armed for 12 s; ``resuming``: frozen at 8 s, a resume
    armed for 12 s."""
    state = RunState()
    if mode == "waiting":
        return state
    state.command(Cmd("start", 0, at=5.0), t_sim=1.0)
    if mode == "armed":
        return state
    state.update(5.0)
    if mode == "running":
        return state
    if mode == "freezing":
        state.command(Cmd("freeze", 1, at=12.0), t_sim=8.0)
        return state
    if mode in ("frozen", "resuming"):
        state.command(Cmd("freeze", 1, at=8.0), t_sim=8.0)
        if mode == "resuming":
            state.command(Cmd("resume", 2, at=12.0, issued_at=8.0), t_sim=8.0)
        return state
    if mode == "done":
        state.duration = 2.0
        state.update(7.0)
        return state
    state.command(Cmd("abort", 2), t_sim=9.0)
    return state


@pytest.mark.parametrize("mode", get_args(Stage))
def test_in_mode_reaches_each_mode(mode: Stage) -> None:
    assert in_mode(mode).stage == mode


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


def test_a_freeze_without_at_freezes_now() -> None:
    state = in_mode("running")
    assert state.command(Cmd("freeze", 1), t_sim=7.0) == [Event("frozen", 7.0)]
    assert state.frozen_at == 7.0


def test_a_resume_at_an_instant_before_the_freeze_is_ignored() -> None:
    # Resumed "at 7" a run frozen at 8 would resume before it froze: an agent that took
    # the resume before the freeze could not agree with one that took them in order.
    state = in_mode("frozen")  # frozen at 8
    assert state.command(Cmd("resume", 2, at=7.0), t_sim=8.0) == [
        Event("ignored", 8.0, "resume at 7.000 s, before the freeze at 8.000 s")
    ]
    assert (state.mode, state.frozen_at, state.frozen_total) == ("frozen", 8.0, 0.0)
    # Without an instant, on receipt (stamped), it resumes now: nothing is made up.
    assert state.command(Cmd("resume", 3, issued_at=8.0), t_sim=8.0) == [Event("resumed", 8.0)]
    assert state.frozen_total == 0.0


@pytest.mark.parametrize("at", [-1e9, 0.0, 48.9])
def test_a_resume_whose_instant_passed_is_ignored(at: float) -> None:
    # Acted on at -1e9, a resume would jump the run's clock by the whole freeze.
    state = in_mode("frozen")
    before = (state.mode, state.frozen_at, state.frozen_total)
    (event,) = state.command(Cmd("resume", 3, at=at), t_sim=50.0)
    assert event.kind == "ignored" and "instant passed" in event.detail
    assert (state.mode, state.frozen_at, state.frozen_total) == before


@pytest.mark.parametrize("at", [0.0, 48.9])
def test_a_freeze_whose_instant_passed_freezes_now(at: float) -> None:
    # Acted on at 0, a freeze would rewind the run's clock by 45 s (the leader slewing
    # back to the maneuver's first heading); ignored, a freeze 1.3 s late on a congested
    # link would leave the platforms flying.
    state = in_mode("running")
    late = f"late: its instant passed {50.0 - at:.3f} s ago; frozen now"
    assert state.command(Cmd("freeze", 3, at=at), t_sim=50.0) == [Event("frozen", 50.0, late)]
    assert state.mode == "frozen" and state.frozen_at == 50.0
    assert state.last == Applied("frozen", 50.0, 45.0, late)  # what status and log say


@pytest.mark.parametrize("kind", ["resume", "start"])
def test_a_command_on_receipt_issued_long_ago_is_ignored(kind: str) -> None:
    # Sent on receipt, it waited behind a cut link: acted on, a resume would set the
    # platform moving whenever it came (rule 6). A freeze so late is still a freeze (above).
    modes: dict[str, Mode] = {"resume": "frozen", "start": "waiting"}
    state = in_mode(modes[kind])
    before = (state.mode, state.frozen_at, state.frozen_total)
    (event,) = state.command(Cmd(kind, 3, issued_at=48.9), t_sim=50.0)
    assert event.kind == "ignored" and "issued 1.1 s ago" in event.detail
    assert (state.mode, state.frozen_at, state.frozen_total) == before
    # Fresh, it acts on receipt as before.
    events = state.command(Cmd(kind, 3, issued_at=49.5), t_sim=50.0)
    assert events and events[0].kind in ("resumed", "armed"), events
    late_freeze = in_mode("running").command(Cmd("freeze", 3, issued_at=10.0), t_sim=50.0)
    assert late_freeze == [Event("frozen", 50.0)]


def test_a_start_without_a_duration_is_ignored_unless_the_agent_has_one() -> None:
    # A hand-made start with no duration, to an agent with none, would fly until an abort.
    state = RunState()
    (event,) = state.command(Cmd("start", at=5.0, duration=None), t_sim=1.0)
    assert event.kind == "ignored" and "a run must end" in event.detail
    assert state.mode == "waiting"
    assert RunState(duration=3.0).command(Cmd("start", at=5.0, duration=None), t_sim=1.0) == [
        Event("armed", 5.0)
    ]


# ------------------------------------------------------------------ ignored commands


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


def test_a_resume_now_unsynchronized_is_ignored() -> None:
    state = in_mode("frozen")
    assert state.command(Cmd("resume", 10, issued_at=9.0), t_sim=None) == [
        Event("ignored", None, "resume while frozen")
    ]
    assert state.mode == "frozen"


def test_a_freeze_unsynchronized_freezes_at_the_last_reference_time_known() -> None:
    # Its reference link contested, the agent freezes at the last reference time it
    # knows rather than run on while the others freeze.
    state = in_mode("running")
    state.update(7.5)
    assert state.command(Cmd("freeze", 10), t_sim=None) == [Event("frozen", 7.5)]
    assert state.mode == "frozen" and state.frozen_at == 7.5


def test_a_resume_that_does_not_say_when_it_was_sent_is_ignored() -> None:
    # An unstamped resume (a script, an older ctl) may come an hour late and would set
    # platforms moving then.
    state = in_mode("frozen")
    (event,) = state.command(Cmd("resume", 10), t_sim=3600.0)
    assert event.kind == "ignored" and "without at or issued_at" in event.detail
    assert state.mode == "frozen"


# ------------------------------------------------------------------ run time


def test_run_time_is_none_before_the_start_or_without_time() -> None:
    assert RunState().run_time(5.0) is None
    assert in_mode("armed").run_time(6.0) is None  # armed: not started yet
    assert in_mode("running").run_time(None) is None
    assert in_mode("running").run_time(4.0) == 0.0  # never negative


def test_the_schema_command_is_a_run_command() -> None:
    command: RunCommand = Command(command="start", seq=0, at=5.0, duration=10.0)
    state = RunState()
    assert state.command(command, t_sim=1.0) == [Event("armed", 5.0)]


# ------------------------------------------------------------------ modes and the run's end


def test_running_freeze_freezes_and_run_time_stops() -> None:
    state = in_mode("running")
    late = "late: received 0.100 s after its instant"
    assert state.command(Cmd("freeze", 1, at=7.9), t_sim=8.0) == [Event("frozen", 7.9, late)]
    assert (state.mode, state.frozen_at) == ("frozen", 7.9)
    assert state.run_time(20.0) == pytest.approx(2.9)  # held at the freeze


def test_a_freeze_or_resume_in_the_future_arms_and_applies_at_its_instant() -> None:
    state = in_mode("running")  # started at 5
    assert state.command(Cmd("freeze", 1, at=38.0), t_sim=8.0) == [Event("freezing", 38.0)]
    assert (state.mode, state.stage, state.due) == ("running", "freezing", 38.0)
    assert state.update(37.99) == [] and state.mode == "running"  # flying until then
    assert state.update(38.004) == [Event("frozen", 38.0)]  # the tick after: at its instant
    assert state.last == Applied("frozen", 38.0, 33.0)
    assert state.command(Cmd("resume", 2, at=40.0), t_sim=39.0) == [Event("resuming", 40.0)]
    assert (state.mode, state.stage) == ("frozen", "resuming")
    assert state.run_time(39.5) == pytest.approx(33.0)  # still frozen
    assert state.update(40.01) == [Event("resumed", 40.0)]
    assert state.last == Applied("resumed", 40.0, 33.0)
    assert state.run_time(42.0) == pytest.approx(35.0)  # 37 s since the start, 2 s frozen


def test_frozen_resume_runs_again_less_the_time_frozen() -> None:
    state = in_mode("frozen")  # started at 5, frozen at 8
    assert state.command(Cmd("resume", 2, at=10.0), t_sim=10.0) == [Event("resumed", 10.0)]
    assert state.mode == "running" and state.frozen_at is None
    assert state.frozen_total == pytest.approx(2.0)
    assert state.run_time(12.0) == pytest.approx(5.0)


def test_start_re_arms_an_armed_run() -> None:
    state = in_mode("armed")
    assert state.command(Cmd("start", 10, at=30.0, run_id="b"), t_sim=12.0) == [
        Event("armed", 30.0)
    ]
    assert (state.mode, state.start_at, state.run_id) == ("armed", 30.0, "b")


@pytest.mark.parametrize("mode", ["running", "frozen"])
def test_start_while_running_or_frozen_is_ignored(mode: Mode) -> None:
    state = in_mode(mode)
    assert state.command(Cmd("start", 10, at=30.0), t_sim=12.0) == [
        Event("ignored", 12.0, f"start while {mode}: abort first")
    ]
    assert state.mode == mode and state.start_at == 5.0


@pytest.mark.parametrize("mode", ["waiting", "armed", "running", "frozen", "done"])
def test_abort_from_any_mode(mode: Mode) -> None:
    state = in_mode(mode)
    assert state.command(Cmd("abort", 10), t_sim=9.5) == [Event("aborted", 9.5)]
    assert state.mode == "aborted"
    assert state.update(100.0) == []


def test_a_second_abort_does_nothing_more() -> None:
    state = in_mode("aborted")
    assert state.command(Cmd("abort", 11), t_sim=9.6) == []
    assert state.mode == "aborted"


@pytest.mark.parametrize("command", ["start", "freeze", "resume"])
def test_after_an_abort_everything_but_abort_and_reset_is_ignored(command: str) -> None:
    state = in_mode("aborted")
    assert state.command(Cmd(command, 10, at=20.0), t_sim=9.5) == [
        Event("ignored", 9.5, f"{command} after abort: fedlab ctl reset first")
    ]
    assert state.mode == "aborted"


def test_the_run_is_done_after_its_duration_and_run_time_holds() -> None:
    state = RunState()
    state.command(Cmd("start", at=5.0, duration=10.0), t_sim=1.0)
    state.update(5.0)
    assert state.update(14.99) == [] and state.mode == "running"
    assert state.fraction(10.0) == pytest.approx(0.5)
    assert state.update(15.02) == [Event("done", 15.0)]
    assert state.mode == "done"
    assert state.run_time(40.0) == pytest.approx(10.0)
    assert state.fraction(40.0) == 1.0


def test_run_time_read_past_the_end_before_the_update_is_the_duration() -> None:
    # A status built between the end's instant and the control step that applies it
    # (a rejoined follower recorded 13.5003 s of a 13.5 s run as running).
    state = RunState()
    state.command(Cmd("start", at=5.0, duration=10.0), t_sim=1.0)
    state.update(14.99)
    assert state.mode == "running"
    assert state.run_time(15.0003) == 10.0
    assert state.update(15.0003) == [Event("done", 15.0)]
    assert state.run_time(15.0003) == 10.0


def test_frozen_time_does_not_count_towards_the_duration() -> None:
    state = RunState()
    state.command(Cmd("start", at=0.0, duration=10.0), t_sim=0.0)
    state.command(Cmd("freeze"), t_sim=4.0)
    state.command(Cmd("resume", issued_at=9.0), t_sim=9.0)  # 5 s frozen
    assert state.update(14.9) == []
    assert state.update(15.0) == [Event("done", 15.0)]


def test_the_agents_duration_applies_when_the_start_gives_none() -> None:
    state = RunState(duration=3.0)
    state.command(Cmd("start", at=0.0, duration=None), t_sim=0.0)
    assert state.update(3.0) == [Event("done", 3.0)]
    state.command(Cmd("start", at=10.0, duration=1.0), t_sim=5.0)
    assert state.duration == 1.0


def test_done_waits_for_the_next_start_which_names_a_new_run() -> None:
    state = RunState(duration=3.0)
    state.command(Cmd("start", at=0.0, run_id="one", duration=None), t_sim=0.0)
    state.update(3.0)
    assert state.mode == "done"
    events = state.command(Cmd("start", at=10.0, run_id="two"), t_sim=5.0)
    assert events == [Event("armed", 10.0)]
    assert (state.mode, state.run_id, state.frozen_at, state.frozen_total) == (
        "armed",
        "two",
        None,
        0.0,
    )
    assert state.update(10.0) == [Event("started", 10.0)]


@pytest.mark.parametrize("mode", ["aborted", "done", "armed"])
def test_reset_brings_back_to_waiting(mode: Mode) -> None:
    state = in_mode(mode)
    assert state.command(Cmd("reset"), t_sim=20.0) == [Event("reset", 20.0)]
    assert (state.mode, state.start_at) == ("waiting", None)
    assert state.update(100.0) == []  # nothing armed any more
    assert state.command(Cmd("start", at=30.0), t_sim=21.0) == [Event("armed", 30.0)]


def test_reset_while_waiting_does_nothing_and_while_running_is_ignored() -> None:
    assert in_mode("waiting").command(Cmd("reset"), t_sim=1.0) == []
    state = in_mode("running")
    assert state.command(Cmd("reset"), t_sim=6.0) == [
        Event("ignored", 6.0, "reset while running: abort first")
    ]


def test_abort_holds_the_run_time_where_it_was() -> None:
    state = in_mode("running")  # started at 5
    state.command(Cmd("abort"), t_sim=9.0)
    assert state.run_time(50.0) == pytest.approx(4.0)
    assert in_mode("armed").command(Cmd("abort"), t_sim=2.0) == [Event("aborted", 2.0)]


def test_autostart_counts_run_time_from_the_first_reference_time() -> None:
    """A lone agent whose platform takes 7.5 s to build starts then, not at clock zero."""
    state = RunState(autostart=True)
    assert state.mode == "armed" and state.start_at is None
    assert state.update(None) == []
    assert state.update(7.5) == [Event("started", 7.5)]
    assert state.run_time(8.0) == pytest.approx(0.5)


def test_a_start_whose_instant_has_passed_is_refused() -> None:
    # At 1000 s a start "at 0" would begin at run time 1000: the leader would enter its
    # maneuver part-way.
    state = RunState()
    (event,) = state.command(Cmd("start", 0, at=0.0), t_sim=1000.0)
    assert event.kind == "ignored" and "start instant passed 1000.0 s ago" in event.detail
    assert state.mode == "waiting"
    # Within a second of it (a command on a slow path): armed, and running at once.
    assert [e.kind for e in state.command(Cmd("start", 1, at=999.5), t_sim=1000.0)] == [
        "armed",
        "started",
    ]


def test_a_freeze_before_the_runs_start_freezes_at_its_start() -> None:
    # A freeze "at 0" would rewind the run time to 0 and move the run's end later.
    state = in_mode("running")  # started at 5 s
    late = "late: received 0.900 s after its instant"
    assert state.command(Cmd("freeze", 1, at=4.5), t_sim=5.4) == [Event("frozen", 5.0, late)]
    assert state.run_time(20.0) == 0.0


def test_a_command_whose_maneuver_is_too_short_to_fly_is_malformed() -> None:
    # A rotation out and back in 1e-12 s would ask a rate of 1e300.
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="duration"):
        Command.model_validate_json(
            '{"command": "start", "seq": 1, "maneuver": {"duration": 1e-12}}'
        )


# ------------------------------------------------------------------ the whole table

MODES: tuple[Mode, ...] = get_args(Mode)
STAGES: tuple[Stage, ...] = get_args(Stage)
EVERY_RULE = list(product(STAGES, COMMANDS))


def documented_rule(mode: Stage, command: str) -> Outcome:
    """Rules 1 to 5 and 7 of the module's docstring, as they read there, without instants."""
    under_way = ("running", "freezing", "frozen", "resuming")
    if command in ("admit", "handback"):  # rule 7
        return "nothing"
    if command == "abort":  # rule 1
        return "nothing" if mode == "aborted" else "abort"
    if command == "reset":  # rule 2
        if mode in ("aborted", "done", "armed"):
            return "reset"
        return "nothing" if mode == "waiting" else "busy"
    if mode == "aborted":  # rule 3
        return "after abort"
    if command == "start":  # rule 4
        return "busy" if mode in under_way else "arm"
    if command == "freeze":  # rule 5: while running (a second one while armed too)
        if mode == "resuming":
            return "armed first"
        return "freeze" if mode in ("running", "freezing") else "wrong mode"
    assert command == "resume"
    if mode == "freezing":
        return "armed first"
    return "resume" if mode in ("frozen", "resuming") else "wrong mode"


def test_the_table_names_every_command_in_every_mode() -> None:
    assert get_args(Command.model_fields["command"].annotation) == COMMANDS
    assert sorted(COMMAND_RULES) == sorted(EVERY_RULE)
    assert sorted(TIMING_CHECKS) == sorted(COMMANDS)


@pytest.mark.parametrize(("mode", "command"), EVERY_RULE)
def test_the_table_keeps_the_documented_rules(mode: Stage, command: str) -> None:
    assert COMMAND_RULES[mode, command] == rule(mode, command) == documented_rule(mode, command)


def timely(command: str, mode: Stage) -> Cmd:
    """``command`` in time at 9.5 s: sent then, acting then (a start later, at 20 s; a
    resume while a freeze is armed for 12 s, after it, at 12.5 s)."""
    at = {"start": 20.0, "resume": 12.5 if mode == "freezing" else 9.5}.get(command, 9.5)
    return Cmd(command, 10, at=at, issued_at=9.5)


@pytest.mark.parametrize(("mode", "command"), EVERY_RULE)
def test_every_rule_does_what_the_table_says(mode: Stage, command: str) -> None:
    """A command in time, in every stage, has the effect its table entry names."""
    expected: dict[Outcome, tuple[list[Event], Stage]] = {
        "arm": ([Event("armed", 20.0)], "armed"),
        "freeze": ([Event("frozen", 9.5)], "frozen"),
        "resume": ([Event("resumed", 9.5)], "running"),
        "abort": ([Event("aborted", 9.5)], "aborted"),
        "reset": ([Event("reset", 9.5)], "waiting"),
        "nothing": ([], mode),
        "busy": ([Event("ignored", 9.5, f"{command} while {mode}: abort first")], mode),
        "after abort": (
            [Event("ignored", 9.5, f"{command} after abort: fedlab ctl reset first")],
            mode,
        ),
        "wrong mode": ([Event("ignored", 9.5, f"{command} while {mode}")], mode),
        "armed first": (
            [
                Event(
                    "ignored",
                    9.5,
                    f"{command} while {mode}: the armed one applies first (or abort)",
                )
            ],
            mode,
        ),
    }
    state = in_mode(mode)
    events = state.command(timely(command, mode), t_sim=9.5)
    assert (events, state.stage) == expected[COMMAND_RULES[mode, command]]


def snapshot(state: RunState) -> tuple[object, ...]:
    return (
        state.mode, state.start_at, state.frozen_at, state.frozen_total, state.run_id,
        state.armed,
    )  # fmt: skip


@pytest.mark.parametrize(("mode", "command"), EVERY_RULE)
def test_on_receipt_long_after_it_was_sent_only_a_start_or_resume_is_refused(
    mode: Stage, command: str
) -> None:
    """Rule 6 over the whole table: a start or resume on receipt sent 1.1 s before is
    ignored (after an abort, rule 3 answers first); any other command late does what it
    does in time."""
    late_state, fresh_state = in_mode(mode), in_mode(mode)
    before = snapshot(late_state)
    late = late_state.command(Cmd(command, 10, issued_at=8.4), t_sim=9.5)
    fresh = fresh_state.command(Cmd(command, 10, issued_at=9.5), t_sim=9.5)
    if command in ("start", "resume") and mode != "aborted":
        assert late == [Event("ignored", 9.5, f"{command} issued 1.1 s ago")]
        assert snapshot(late_state) == before
    else:
        assert (late, snapshot(late_state)) == (fresh, snapshot(fresh_state))


@pytest.mark.parametrize("mode", STAGES)
def test_a_command_the_table_does_not_name_is_ignored(mode: Stage) -> None:
    events = in_mode(mode).command(Cmd("launch", 10, at=9.5), t_sim=9.5)
    detail = "launch after abort: fedlab ctl reset first" if mode == "aborted" else None
    assert events == [Event("ignored", 9.5, detail or f"launch while {mode}")]


def test_a_late_freeze_never_rewinds_the_run_past_its_last_resume() -> None:
    # Started at 0, frozen at 10, resumed at 20 (run time 10.0); a freeze stamped 19.5
    # that arrives at 20.2 freezes at the resume, not before it: the run's clock (and
    # the leader's maneuver on it) never steps back.
    state = RunState()
    state.command(Cmd("start", 0, at=0.0), t_sim=0.0)
    state.update(0.0)
    state.command(Cmd("freeze", 1, at=10.0), t_sim=10.0)
    state.command(Cmd("resume", 2, at=20.0), t_sim=20.0)
    assert state.run_time(20.0) == pytest.approx(10.0)
    events = state.command(Cmd("freeze", 3, at=19.5), t_sim=20.2)
    assert [e.kind for e in events] == ["frozen"] and events[0].t_sim == pytest.approx(20.0)
    assert state.run_time(20.2) == pytest.approx(10.0)
    state.command(Cmd("resume", 4, at=21.0), t_sim=21.0)
    assert state.run_time(21.5) == pytest.approx(10.5)

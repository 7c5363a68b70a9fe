"""Run modes (federation/core/runstate.py): a freeze and a resume announced for an
instant to come, on simulated reference time. Each arms, then applies at its instant
on every agent alike whenever the command reached it and whenever its loop ticked;
what an abort, a second freeze, a late one and a resume before the freeze do; and
hypothesis's stateful testing over any sequence of commands and ticks."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from federation.core.runstate import LATE_START, Applied, Event, RunState


@dataclass(frozen=True)
class Cmd:
    command: str
    at: float | None = None
    issued_at: float | None = None
    run_id: str | None = "run"
    duration: float | None = 100.0


def running(start: float = 5.0, duration: float = 100.0) -> RunState:
    state = RunState()
    state.command(Cmd("start", at=start, duration=duration), t_sim=start)
    assert state.mode == "running"
    return state


# ------------------------------------------------------------------ one agent


def test_an_abort_while_a_freeze_is_armed_aborts_and_the_freeze_never_applies() -> None:
    state = running()
    state.command(Cmd("freeze", at=20.0), t_sim=10.0)
    assert state.command(Cmd("abort"), t_sim=12.0) == [Event("aborted", 12.0)]
    assert (state.mode, state.armed, state.due) == ("aborted", None, None)
    assert state.update(25.0) == [] and state.run_time(25.0) == pytest.approx(7.0)


def test_an_abort_while_a_resume_is_armed_aborts_frozen() -> None:
    state = running()
    state.command(Cmd("freeze", at=10.0), t_sim=10.0)
    state.command(Cmd("resume", at=20.0, issued_at=12.0), t_sim=12.0)
    state.command(Cmd("abort"), t_sim=13.0)
    assert state.update(30.0) == [] and state.mode == "aborted"
    assert state.run_time(30.0) == pytest.approx(5.0)  # held at the freeze


@pytest.mark.parametrize("order", [(20.0, 18.0), (18.0, 20.0)])
def test_a_second_freeze_while_one_is_armed_keeps_the_earlier_instant(
    order: tuple[float, float],
) -> None:
    # Two operators' freezes, in either order: every agent freezes at 18 s.
    state = running()
    events = [state.command(Cmd("freeze", at=at), t_sim=10.0) for at in order]
    later, earlier = max(order), min(order)
    assert Event("freezing", earlier) in events[0] + events[1]
    refused = [e for e in events[0] + events[1] if e.kind == "ignored"]
    if order[0] == earlier:  # the later one, second, is refused and says why
        assert refused == [
            Event("ignored", 10.0, f"freeze at {later:.3f} s: one is armed for {earlier:.3f} s")
        ]
    else:  # the earlier one, second, re-arms
        assert refused == []
    assert state.due == earlier
    assert state.update(earlier) == [Event("frozen", earlier)]
    assert state.last == Applied("frozen", earlier, earlier - 5.0)


def test_a_second_freeze_whose_instant_passed_while_one_is_armed_freezes_now() -> None:
    state = running()
    state.command(Cmd("freeze", at=20.0), t_sim=10.0)
    late = "late: its instant passed 5.000 s ago; frozen now"
    assert state.command(Cmd("freeze", at=5.5), t_sim=10.5) == [Event("frozen", 10.5, late)]
    assert state.armed is None and state.update(21.0) == []


def test_a_resume_at_an_instant_before_an_armed_freeze_is_refused() -> None:
    state = running()
    state.command(Cmd("freeze", at=20.0), t_sim=10.0)
    (event,) = state.command(Cmd("resume", at=15.0, issued_at=10.0), t_sim=10.5)
    assert event == Event("ignored", 10.5, "resume at 15.000 s, before the freeze at 20.000 s")
    (event,) = state.command(Cmd("resume", at=25.0, issued_at=10.0), t_sim=10.5)
    assert event.kind == "ignored" and "the armed one applies first" in event.detail
    assert state.update(20.0) == [Event("frozen", 20.0)]


def test_a_freeze_while_a_resume_is_armed_is_refused_and_the_resume_applies() -> None:
    state = running()
    state.command(Cmd("freeze", at=10.0), t_sim=10.0)
    state.command(Cmd("resume", at=20.0, issued_at=12.0), t_sim=12.0)
    (event,) = state.command(Cmd("freeze", at=14.0), t_sim=13.0)
    assert event.kind == "ignored" and "freeze while resuming" in event.detail
    assert state.update(20.0) == [Event("resumed", 20.0)]
    assert state.last == Applied("resumed", 20.0, 5.0)


def test_a_second_resume_while_one_is_armed_keeps_the_earlier_instant() -> None:
    state = running()
    state.command(Cmd("freeze", at=10.0), t_sim=10.0)
    state.command(Cmd("resume", at=20.0, issued_at=12.0), t_sim=12.0)
    assert state.command(Cmd("resume", at=18.0, issued_at=12.5), t_sim=12.5) == [
        Event("resuming", 18.0)
    ]
    (event,) = state.command(Cmd("resume", at=19.0, issued_at=12.6), t_sim=12.6)
    assert event == Event("ignored", 12.6, "resume at 19.000 s: one is armed for 18.000 s")
    assert state.update(18.2) == [Event("resumed", 18.0)]


def test_a_freeze_armed_for_after_the_runs_end_never_applies() -> None:
    state = running(start=5.0, duration=10.0)  # ends at 15
    assert state.command(Cmd("freeze", at=16.0), t_sim=14.0) == [Event("freezing", 16.0)]
    assert state.update(16.5) == [Event("done", 15.0)]
    assert (state.mode, state.armed, state.run_time(20.0)) == ("done", None, 10.0)
    assert state.last == Applied("done", 15.0, 10.0)


def test_a_freeze_armed_before_the_runs_end_applies_even_on_a_late_tick() -> None:
    # The loop's tick comes after both the freeze's instant and the run's end: the
    # freeze came first, so the run is frozen, not done.
    state = running(start=5.0, duration=10.0)
    state.command(Cmd("freeze", at=14.0), t_sim=13.0)
    assert state.update(16.0) == [Event("frozen", 14.0)]
    assert state.run_time(16.0) == pytest.approx(9.0)


def test_the_last_transition_is_the_start_at_its_instant_with_no_run_time() -> None:
    state = RunState()
    state.command(Cmd("start", at=5.0), t_sim=1.0)
    assert state.last is None
    state.update(5.007)  # the loop's tick after the start
    assert state.last == Applied("started", 5.0, 0.0)
    state.command(Cmd("abort"), t_sim=6.0)
    assert state.last == Applied("aborted", 6.0, 1.0)
    state.command(Cmd("reset"), t_sim=7.0)
    assert state.last is None


# ------------------------------------------------------------------ agents alike


@given(
    delays=st.lists(st.floats(0.0, 0.3), min_size=3, max_size=3),
    phases=st.lists(st.floats(0.0, 0.01, exclude_max=True), min_size=3, max_size=3),
    freeze_in=st.floats(0.31, 2.0),
    frozen_for=st.floats(0.5, 5.0),
)
@settings(max_examples=200, deadline=None)
def test_agents_freeze_and_resume_at_the_same_run_time_whatever_their_delay_and_tick(
    delays: list[float], phases: list[float], freeze_in: float, frozen_for: float
) -> None:
    """Three agents, the commands reaching each after its own delay (under the lead),
    each ticking at 100 Hz on its own phase: all freeze at the same run time and resume
    at the same one, to the bit."""
    issued = 20.0
    freeze = Cmd("freeze", at=issued + freeze_in, issued_at=issued)
    resume_issued = freeze.at + frozen_for  # type: ignore[operator]
    resume = Cmd("resume", at=resume_issued + freeze_in, issued_at=resume_issued)
    applied: list[tuple[Applied | None, Applied | None]] = []
    for delay, phase in zip(delays, phases, strict=True):
        state = running(start=5.0)
        inbox = [(issued + delay, freeze), (resume_issued + delay, resume)]
        froze = None
        t = 10.0 + phase
        while t < resume.at + 0.05:  # type: ignore[operator]
            while inbox and inbox[0][0] <= t:
                _, cmd = inbox.pop(0)
                state.command(cmd, t_sim=t)
            state.update(t)
            if froze is None and state.mode == "frozen":
                froze = state.last
            t += 0.01
        applied.append((froze, state.last))
    assert all(a == applied[0] for a in applied), applied
    froze, resumed = applied[0]
    assert froze is not None and froze.kind == "frozen" and froze.at == freeze.at
    assert resumed is not None and resumed.kind == "resumed" and resumed.at == resume.at
    assert froze.run_time == resumed.run_time


# ------------------------------------------------------------------ any sequence


class AnnouncedTransitions(RuleBasedStateMachine):
    """Freezes, resumes and aborts, each announced for an instant to come or past (by
    up to twice ``LATE_START``), or on receipt; ticks of reference time in between."""

    def __init__(self) -> None:
        super().__init__()
        self.state = running(start=0.0, duration=60.0)
        self.now = 0.0
        self.run_time = 0.0

    def _send(self, command: str, offset: float | None) -> None:
        at = None if offset is None else self.now + offset
        self.state.command(Cmd(command, at=at, issued_at=self.now), t_sim=self.now)

    @rule(offset=st.none() | st.floats(-2 * LATE_START, 3.0))
    def freeze(self, offset: float | None) -> None:
        self._send("freeze", offset)

    @rule(offset=st.none() | st.floats(-2 * LATE_START, 3.0))
    def resume(self, offset: float | None) -> None:
        self._send("resume", offset)

    @rule()
    def abort(self) -> None:
        self._send("abort", None)

    @rule(dt=st.floats(0.001, 2.0))
    def tick(self, dt: float) -> None:
        self.now += dt
        self.state.update(self.now)

    @invariant()
    def armed_only_in_its_mode_and_only_for_later(self) -> None:
        armed = self.state.armed
        if armed is None:
            return
        command, at = armed
        assert self.state.mode == ("running" if command == "freeze" else "frozen")
        last = self.state.last_t_sim
        assert last is not None and at > last  # an instant reached has applied

    @invariant()
    def no_transition_applied_in_the_future(self) -> None:
        last = self.state.last
        if last is not None and last.at is not None:
            assert last.at <= self.now + 1e-9

    @invariant()
    def run_time_bounded(self) -> None:
        run_time = self.state.run_time(self.now)
        assert run_time is not None and 0.0 <= run_time <= 60.0 + 1e-9

    @invariant()
    def a_resume_never_makes_up_run_time(self) -> None:
        # Frozen time is never negative: a resume applies at or after its freeze.
        assert self.state.frozen_total >= 0.0


TestAnnouncedTransitions = AnnouncedTransitions.TestCase
TestAnnouncedTransitions.settings = settings(
    max_examples=150, stateful_step_count=30, deadline=None
)

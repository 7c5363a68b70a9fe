"""The safety supervisor (federation/core/holds.py): the table's rules, proved over
arbitrary sequences of triggers (hypothesis's stateful testing), and together with a
real run state driven by arbitrary commands."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from federation.core.holds import (
    BY_HOLD,
    RULES,
    Hold,
    Release,
    Supervisor,
    Trigger,
    holds_table_markdown,
)
from federation.core.runstate import MOVING_MODES, RunState

FOR_GOOD = frozenset(r.hold for r in RULES if r.release is Release.NEVER)
RESET_LIFTS = frozenset(r.hold for r in RULES if Trigger.OPERATOR_RESET in r.lifted_by)
RUN_HOLDS = frozenset(r.hold for r in RULES if r.release is Release.RUN)
TRIGGERS = st.sampled_from(list(Trigger))


def test_every_hold_has_one_row_and_no_trigger_both_sets_and_lifts_it() -> None:
    assert [r.hold for r in RULES] == list(Hold)  # one row each, in rank order
    for r in RULES:
        assert r.set_by not in r.lifted_by, r.hold
        assert (r.release is Release.NEVER) == (not r.lifted_by), r.hold
        assert (r.release is Release.OPERATOR) == (r.lifted_by == {Trigger.OPERATOR_RESET})


def test_the_table_names_what_the_docs_promise() -> None:
    assert {Hold.NAME_TAKEN, Hold.WORKSPACE, Hold.NONFINITE, Hold.ENDED} == FOR_GOOD
    assert {Hold.FIX_RESTART, Hold.ABORTED, Hold.DONE} == RESET_LIFTS
    assert BY_HOLD[Hold.ABORTED].lifted_by == {Trigger.OPERATOR_RESET}
    # A start is refused (preflight) for every hold but the run's own.
    assert {r.hold for r in RULES if not r.preflight} == RUN_HOLDS


def test_a_new_supervisor_waits_and_a_start_releases() -> None:
    s = Supervisor()
    assert s.hold is Hold.WAITING and not s.may_open
    s.apply(Trigger.RUN_ARMED)
    assert s.hold is Hold.WAITING
    change = s.apply(Trigger.RUN_STARTED)
    assert change.lifted == {Hold.WAITING} and s.may_open and s.hold is None


def test_a_rejoin_lifts_only_the_run_holds_of_waiting() -> None:
    # A restarted agent (waiting) that joins a run under way is released as a start
    # releases it; a fault or a condition standing still holds it.
    assert {r.hold for r in RULES if Trigger.RUN_REJOINED in r.lifted_by} == {
        Hold.WAITING,
        Hold.RESET,
    }
    assert not any(r.set_by is Trigger.RUN_REJOINED for r in RULES)
    s = Supervisor()
    assert s.apply(Trigger.RUN_REJOINED).lifted == {Hold.WAITING} and s.may_open
    s = Supervisor()
    s.apply(Trigger.LINK_STALE)
    s.apply(Trigger.RUN_REJOINED)
    assert s.hold is Hold.STALE and not s.may_open
    s = Supervisor(())
    s.apply(Trigger.RUN_ABORTED)
    s.apply(Trigger.RUN_REJOINED)
    assert s.hold is Hold.ABORTED, "a rejoin lifted an abort"


def test_the_highest_ranked_hold_is_shown_and_the_others_still_stand() -> None:
    s = Supervisor(())
    for trigger in (Trigger.LINK_STALE, Trigger.ROUTER_LOST, Trigger.RUN_DONE):
        s.apply(trigger)
    assert s.hold is Hold.DONE
    assert s.blocking() is Hold.NO_ROUTER  # preflight names the fault, not the run's end
    s.apply(Trigger.RUN_ARMED)
    assert s.hold is Hold.NO_ROUTER
    s.apply(Trigger.ROUTER_BACK)
    assert s.hold is Hold.STALE
    s.apply(Trigger.RUN_STARTED)
    assert s.hold is Hold.STALE and not s.may_open  # the start lifts only waiting
    s.apply(Trigger.LINK_RESUMED)
    assert s.may_open


@pytest.mark.parametrize("before", [Trigger.RUN_DONE, Trigger.RUN_ABORTED, None])
def test_a_confirmed_reset_lifts_a_restarted_estimate_in_every_mode(
    before: Trigger | None,
) -> None:
    # The fix_restart that stayed: a reset while waiting changed no run mode, and so
    # lifted nothing. The reset itself is the trigger, whatever the mode.
    s = Supervisor()
    if before is not None:
        s.apply(before)
    s.apply(Trigger.FIX_RESTARTED)
    assert s.hold in (Hold.FIX_RESTART,)
    s.apply(Trigger.OPERATOR_RESET)
    assert not s.standing & RESET_LIFTS
    assert s.hold is Hold.RESET


def test_docs_holds_md_is_the_table() -> None:
    from pathlib import Path

    doc = (Path(__file__).parents[3] / "docs" / "holds.md").read_text(encoding="utf-8")
    assert holds_table_markdown() in doc, "regenerate: fedlab schemas --holds"


def _affects(trigger: Trigger) -> frozenset[Hold]:
    return frozenset(r.hold for r in RULES if r.set_by is trigger or trigger in r.lifted_by)


@given(st.lists(TRIGGERS, max_size=40), TRIGGERS, TRIGGERS)
def test_triggers_on_different_holds_commute(prefix: list[Trigger], a: Trigger, b: Trigger) -> None:
    if _affects(a) & _affects(b):
        return
    one, two = Supervisor(), Supervisor()
    for t in prefix:
        one.apply(t)
        two.apply(t)
    one.apply(a)
    one.apply(b)
    two.apply(b)
    two.apply(a)
    assert one.standing == two.standing


@given(st.lists(TRIGGERS, max_size=60))
def test_each_hold_stands_as_its_own_last_trigger_says(triggers: list[Trigger]) -> None:
    # The decision for a hold depends only on the triggers that name it, in their
    # order: the last that sets or lifts it decides.
    s = Supervisor(())
    for t in triggers:
        s.apply(t)
    for r in RULES:
        mine = [t for t in triggers if t is r.set_by or t in r.lifted_by]
        if r.release is Release.NEVER:
            expected = r.set_by in mine
        else:
            expected = bool(mine) and mine[-1] is r.set_by
        assert s.holds(r.hold) == expected, (r.hold, mine)


class Holds(RuleBasedStateMachine):
    """Arbitrary triggers; a model of what the rules promise, checked at every step."""

    def __init__(self) -> None:
        super().__init__()
        self.s = Supervisor()
        self.for_good: set[Hold] = set()
        self.aborted = False

    @rule(trigger=TRIGGERS)
    def trigger(self, trigger: Trigger) -> None:
        before = self.s.standing
        change = self.s.apply(trigger)
        assert before - change.lifted | change.set == self.s.standing
        assert not change.lifted & FOR_GOOD, "a hold for good was lifted"
        self.for_good |= self.s.standing & FOR_GOOD
        if trigger is Trigger.RUN_ABORTED:
            self.aborted = True
        elif trigger is Trigger.OPERATOR_RESET:
            self.aborted = False
            assert not self.s.standing & RESET_LIFTS, "a confirmed reset left a hold it lifts"
        for hold in change.lifted:
            assert trigger in BY_HOLD[hold].lifted_by
        if trigger is Trigger.RUN_REJOINED:  # a rejoin lifts only what a start would
            assert change.lifted <= {Hold.WAITING, Hold.RESET}, change
            assert not change.set

    @precondition(lambda self: self.aborted)
    @rule(trigger=TRIGGERS.filter(lambda t: t is not Trigger.OPERATOR_RESET))
    def anything_but_a_reset_after_an_abort(self, trigger: Trigger) -> None:
        self.s.apply(trigger)
        assert self.s.holds(Hold.ABORTED), f"{trigger} lifted an abort"

    @invariant()
    def valves_open_only_when_nothing_holds(self) -> None:
        assert self.s.may_open == (not self.s.standing)
        assert (self.s.hold is None) == self.s.may_open
        if self.aborted:
            assert not self.s.may_open

    @invariant()
    def holds_for_good_stay(self) -> None:
        assert self.for_good <= self.s.standing


TestHolds = Holds.TestCase
TestHolds.settings = settings(max_examples=300, stateful_step_count=60, deadline=None)


@dataclass
class _Cmd:
    command: str
    at: float | None = None
    run_id: str | None = "r"
    duration: float | None = 5.0
    issued_at: float | None = None


_RUN_TRIGGER = {
    "armed": Trigger.RUN_ARMED,
    "started": Trigger.RUN_STARTED,
    "rejoined": Trigger.RUN_REJOINED,
    "done": Trigger.RUN_DONE,
    "aborted": Trigger.RUN_ABORTED,
}
COMMANDS = st.sampled_from(["start", "freeze", "resume", "abort", "reset"])
CONDITIONS = st.sampled_from(
    [
        Trigger.LINK_STALE,
        Trigger.LINK_RESUMED,
        Trigger.CONTESTED,
        Trigger.CONTEST_CLEARED,
        Trigger.ROUTER_LOST,
        Trigger.ROUTER_BACK,
        Trigger.FIX_RESTARTED,
    ]
)
STEPS = st.lists(
    st.one_of(
        st.tuples(st.just("command"), COMMANDS, st.sampled_from([None, -0.5, 0.0, 0.5])),
        st.tuples(st.just("time"), st.floats(0.0, 3.0), st.none()),
        st.tuples(st.just("condition"), CONDITIONS, st.none()),
        # A run under way others announce: begun this long ago (s of run time).
        st.tuples(st.just("rejoin"), st.sampled_from([-1.0, 0.0, 3.0, 9.9, 12.0]), st.none()),
    ),
    max_size=50,
)


@settings(max_examples=400, deadline=None)
@given(STEPS, st.booleans())
def test_with_a_real_run_state_the_valves_open_only_in_a_run_under_way(
    steps: list[tuple[str, object, object]], autostart: bool
) -> None:
    # The agent's wiring in miniature: the run state's events and each applied reset
    # become triggers. Valves open only running or frozen; a run under way with no
    # condition standing is never held by a run hold left over.
    run = RunState(autostart=autostart, duration=10.0)
    s = Supervisor()
    t = 100.0
    for kind, what, arg in steps:
        if kind == "time":
            assert isinstance(what, float)
            t += what
            events = run.update(t)
        elif kind == "condition":
            assert isinstance(what, Trigger)
            s.apply(what)
            continue
        elif kind == "rejoin":
            assert isinstance(what, float)
            events = run.rejoin("r", t - what, 0.0, 10.0, t)
        else:
            assert isinstance(what, str)
            at = None if arg is None else t + float(str(arg))
            events = run.command(_Cmd(what, at=at, issued_at=t), t)
            if what == "reset" and not any(e.kind == "ignored" for e in events):
                s.apply(Trigger.OPERATOR_RESET)
        for event in events:
            if event.kind in _RUN_TRIGGER:
                s.apply(_RUN_TRIGGER[event.kind])
        if s.may_open:
            assert run.mode in MOVING_MODES, (run.mode, s.standing)
        if run.mode in MOVING_MODES:
            assert not s.standing & RUN_HOLDS, (run.mode, s.standing)


def test_rank_order_is_total_and_stable() -> None:
    ranks = [r.hold for r in RULES]
    for a, b in itertools.combinations(ranks, 2):
        s = Supervisor((a, b))
        assert s.hold is a


def test_readers_on_another_thread_never_see_the_holds_change_under_them() -> None:
    # A status (preflight's blocking(), the shown hold) is built on the loop's thread
    # while a command applies triggers on Zenoh's: iterating a set changed meanwhile had
    # raised out of the status and ended the agent's loop.
    import sys
    import threading

    supervisor = Supervisor({Hold.WAITING, Hold.STALE, Hold.CONTESTED, Hold.NO_ROUTER})
    stop = threading.Event()

    def commands() -> None:
        for _ in range(200_000):  # bounded: a run done, then armed again, and again
            if stop.is_set():
                return
            supervisor.apply(Trigger.RUN_DONE)
            supervisor.apply(Trigger.RUN_ARMED)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    writer = threading.Thread(target=commands)
    writer.start()
    try:
        for _ in range(100_000):
            assert supervisor.blocking() in (Hold.CONTESTED,)
            assert supervisor.hold is not None
    finally:
        stop.set()
        writer.join(10.0)
        sys.setswitchinterval(interval)

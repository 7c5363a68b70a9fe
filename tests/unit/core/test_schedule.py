"""Deadlines of an agent's periodic tasks (federation/core/schedule.py)."""

from __future__ import annotations

import math

import pytest

from federation.core.schedule import Due, Timetable, next_tick


def test_next_tick_stays_on_the_grid() -> None:
    assert next_tick(1.0, 0.1, 1.05) == pytest.approx(1.1)


def test_next_tick_skips_missed_ticks_instead_of_bursting() -> None:
    assert next_tick(1.0, 0.1, 1.35) == pytest.approx(1.45)  # 1.1 .. 1.3 skipped
    assert next_tick(1.0, 0.1, 1.1) == pytest.approx(1.2)  # a tick exactly now is past


def table(duration: float | None = None, phase: float = 0.0) -> Timetable:
    """Control 100 Hz, pose 20 Hz, sync 10 Hz, status 1 Hz, from t0 = 0."""
    return Timetable(0.0, 0.01, 0.05, 0.1, 1.0, duration=duration, phase=phase)


def test_everything_but_status_is_due_at_t0() -> None:
    t = table()
    assert t.due(0.0) == Due(control=True, pose=True, sync=True, lateness=0.0)
    assert t.next_wake() == pytest.approx(0.01)


def test_status_first_comes_one_period_plus_the_phase_after_t0() -> None:
    t = table(phase=0.25)
    assert t.next_status == pytest.approx(1.25)
    assert not t.due(1.2).status
    assert t.due(1.25).status


def test_a_sync_phase_moves_the_first_query_onto_a_later_control_tick() -> None:
    t = Timetable(0.0, 0.01, 0.05, 0.1, 1.0, sync_phase=0.03)
    assert not t.due(0.0).sync
    assert not t.due(0.01).sync
    assert not t.due(0.02).sync
    assert t.due(0.03).sync  # on the fourth control tick, then every 0.1 s
    assert t.next_sync == pytest.approx(0.13)


def test_tasks_fire_at_their_own_rates() -> None:
    t = table()
    counts = {"control": 0, "pose": 0, "sync": 0, "status": 0}
    now = 0.0
    while now < 2.0 - 1e-9:  # bounded: 2 s of wake-ups
        due = t.due(now)
        for name in counts:
            counts[name] += getattr(due, name)
        now = t.next_wake()
    assert counts == {"control": 200, "pose": 40, "sync": 20, "status": 1}


def test_a_late_control_tick_reports_its_lateness_and_an_overrun() -> None:
    t = table()
    t.due(0.0)
    due = t.due(0.012)  # 2 ms late: no tick lost
    assert due.control and due.lateness == pytest.approx(0.002) and not due.overrun
    due = t.due(0.05)  # ticks 0.02 .. 0.04 lost
    assert due.lateness == pytest.approx(0.03) and due.overrun
    assert t.next_control == pytest.approx(0.06)


def test_an_armed_start_runs_the_control_step_between_ticks() -> None:
    t = table()
    t.due(0.0)
    assert t.next_wake(start_at=0.004) == 0.004
    due = t.due(0.004, start_at=0.004)
    assert due.control and due.lateness is None  # no tick came: nothing late
    assert not (due.pose or due.sync or due.status)
    assert t.next_control == pytest.approx(0.01)  # the grid is unchanged


def test_the_duration_finishes_and_nothing_else_runs() -> None:
    t = table(duration=1.0)
    assert t.next_wake() == 0.0
    assert t.due(1.0) == Due(finished=True)
    assert table().deadline == math.inf
    assert table(duration=2.5).next_wake(start_at=9.0) == 0.0

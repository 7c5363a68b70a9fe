"""A run joined under way (federation/core/runstate.py's RunState.rejoin): from waiting
only, running at once on the run's own clock, to the same end."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from federation.core.runstate import Applied, RunState


@dataclass(frozen=True)
class Cmd:
    command: str
    seq: int = 0
    at: float | None = None
    run_id: str | None = "run"
    duration: float | None = 20.0
    issued_at: float | None = None


def test_a_waiting_run_state_joins_at_the_present_run_time() -> None:
    run = RunState()
    events = run.rejoin("r1", start_at=100.0, frozen_total=1.5, duration=20.0, t_sim=108.0)
    assert [e.kind for e in events] == ["rejoined"]
    assert events[0].t_sim == 108.0 and "6.500" in events[0].detail
    assert run.mode == "running" and run.run_id == "r1" and run.duration == 20.0
    assert run.run_time(108.0) == pytest.approx(6.5)
    assert run.last is not None and run.last.run_time == pytest.approx(6.5)
    assert run.last == Applied("rejoined", 108.0, run.last.run_time, events[0].detail)


def test_a_rejoined_run_ends_at_the_run_s_own_end_instant() -> None:
    run = RunState()
    run.rejoin("r1", 100.0, 0.0, 20.0, 106.0)
    assert run.update(119.9) == []
    events = run.update(120.01)
    assert [e.kind for e in events] == ["done"]
    assert events[0].t_sim == pytest.approx(120.0)  # the others' end instant
    assert run.run_time(130.0) == pytest.approx(20.0)


def test_a_rejoined_run_takes_freeze_and_abort_like_any_run() -> None:
    run = RunState()
    run.rejoin("r1", 100.0, 0.0, 20.0, 106.0)
    assert [e.kind for e in run.command(Cmd("freeze", at=107.0), 106.5)] == ["freezing"]
    assert [e.kind for e in run.update(107.0)] == ["frozen"]
    assert [e.kind for e in run.command(Cmd("abort"), 108.0)] == ["aborted"]


@pytest.mark.parametrize("mode_of", ["armed", "running", "done", "aborted"])
def test_only_a_waiting_run_state_rejoins(mode_of: str) -> None:
    run = RunState()
    run.command(Cmd("start", at=100.0), 99.0)
    if mode_of in ("running", "done", "aborted"):
        run.update(100.0)
    if mode_of == "done":
        run.update(121.0)
    if mode_of == "aborted":
        run.command(Cmd("abort"), 101.0)
    assert run.mode == mode_of
    before = (run.mode, run.start_at, run.last)
    events = run.rejoin("r2", 50.0, 0.0, 100.0, 101.0)
    assert [e.kind for e in events] == ["ignored"] and mode_of in events[0].detail
    assert (run.mode, run.start_at, run.last) == before


@pytest.mark.parametrize(
    ("start_at", "t_sim", "why"),
    [
        (100.0, None, "not synchronized"),
        (100.0, 99.0, "no run then"),  # not begun
        (100.0, 120.0, "no run then"),  # ended
    ],
)
def test_a_rejoin_outside_the_run_is_ignored(
    start_at: float, t_sim: float | None, why: str
) -> None:
    run = RunState()
    events = run.rejoin("r1", start_at, 0.0, 20.0, t_sim)
    assert [e.kind for e in events] == ["ignored"] and why in events[0].detail
    assert run.mode == "waiting" and run.run_id is None

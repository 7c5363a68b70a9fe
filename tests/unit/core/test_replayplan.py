"""The replay's pure decisions: which recorded pose is due at a run time, which live run
is played against, and the refusal table walked row by row (simulated time)."""

from __future__ import annotations

import pytest

from federation.core.replayplan import (
    REFUSALS,
    RecordedPose,
    ReplayPlan,
    RunWatch,
    Target,
    refusals,
)
from federation.core.wire import Pose


def poses(*times: float) -> list[RecordedPose]:
    return [RecordedPose(t, Pose(heading=t)) for t in times]


def test_each_pose_is_due_when_run_time_reaches_it() -> None:
    plan = ReplayPlan(poses(0.0, 0.05, 0.10))
    assert plan.due(-0.01) is None
    first = plan.due(0.0)
    assert first is not None and first.run_time == 0.0
    assert plan.due(0.049) is None and plan.next_due == 0.05
    second = plan.due(0.05)
    assert second is not None and second.pose.heading == 0.05
    third = plan.due(0.2)
    assert third is not None and third.run_time == 0.10
    assert plan.finished and plan.given == 3 and plan.skipped == 0


def test_a_late_step_gives_the_latest_pose_and_skips_the_older() -> None:
    plan = ReplayPlan(poses(0.0, 0.05, 0.10, 0.15))
    late = plan.due(0.12)
    assert late is not None and late.run_time == 0.10
    assert plan.skipped == 2 and plan.given == 1 and plan.last_run_time == 0.10
    assert plan.due(0.12) is None  # never given twice


def test_a_run_joined_under_way_plays_from_its_present() -> None:
    plan = ReplayPlan(poses(0.0, 1.0, 2.0, 3.0))
    assert plan.skip_to(2.0) == 2
    due = plan.due(2.0)
    assert due is not None and due.run_time == 2.0


def test_poses_out_of_order_are_an_error() -> None:
    plan = ReplayPlan(poses(0.0, 1.0, 0.5))
    with pytest.raises(ValueError, match="out of run-time order"):
        plan.due(1.0)


def test_the_plan_reads_its_poses_lazily() -> None:
    taken: list[float] = []

    def stream() -> object:
        for t in (0.0, 1.0, 2.0):
            taken.append(t)
            yield RecordedPose(t, Pose())

    plan = ReplayPlan(stream())  # type: ignore[arg-type]
    plan.due(0.0)
    assert taken == [0.0, 1.0]  # the one given and the one peeked, no more


STATUS = {"agent": "rome/pinocchio", "reference": "rome/pinocchio", "run_id": "r1"}


def test_the_run_is_the_one_the_live_agents_announce() -> None:
    watch = RunWatch("kiruna/knatte")
    watch.observe("rome/pinocchio", STATUS | {"mode": "waiting", "start_at": None})
    assert watch.run is None
    watch.observe("rome/pinocchio", STATUS | {"mode": "armed", "start_at": 100.0})
    assert watch.run is not None and watch.run.run_time(99.0) == -1.0
    watch.observe("rome/pinocchio", STATUS | {"mode": "running", "start_at": 100.0})
    assert watch.run.run_time(103.5) == 3.5
    watch.observe(
        "rome/pinocchio", STATUS | {"mode": "frozen", "start_at": 100.0, "frozen_total": 0.0}
    )
    assert watch.run.run_time(104.0) is None  # paused
    watch.observe(
        "rome/pinocchio", STATUS | {"mode": "running", "start_at": 100.0, "frozen_total": 2.0}
    )
    assert watch.run.run_time(106.0) == 4.0
    assert watch.ended is None


@pytest.mark.parametrize("mode", ["aborted", "done"])
def test_an_aborted_or_finished_run_ends_the_replay(mode: str) -> None:
    watch = RunWatch("kiruna/knatte")
    watch.observe("rome/pinocchio", STATUS | {"mode": "running", "start_at": 1.0})
    watch.observe("other/agent", STATUS | {"mode": mode, "agent": "other/agent"})
    assert watch.ended is None  # not an announcer of this run
    watch.observe("rome/pinocchio", STATUS | {"mode": mode, "start_at": 1.0})
    assert watch.ended is not None and mode in watch.ended


def test_own_and_other_replays_statuses_are_not_heard() -> None:
    watch = RunWatch("kiruna/knatte")
    watch.observe("kiruna/knatte", STATUS | {"mode": "running", "start_at": 1.0})
    watch.observe("lab/ghost", STATUS | {"mode": "running", "start_at": 1.0, "replay": {}})
    assert watch.run is None
    watch.observe("rome/pinocchio", STATUS | {"mode": "running", "start_at": 1.0, "run_id": "a"})
    watch.observe("lab/x", STATUS | {"mode": "running", "start_at": 9.0, "run_id": "b"})
    assert watch.run is not None and watch.run.run_id == "a"  # the first run announced


ALLOWED = Target("kiruna/knatte", "kiruna/knatte", live=False, recorded_hardware=False)
# One target per row that makes that row (and only it) apply.
ONLY = {
    "name_live": ALLOWED.__class__(**{**ALLOWED.__dict__, "live": True}),
    "own_name_real": ALLOWED.__class__(**{**ALLOWED.__dict__, "recorded_hardware": True}),
    "own_name_unknown": ALLOWED.__class__(**{**ALLOWED.__dict__, "recorded_hardware": None}),
    "target_real": Target(
        "kiruna/knatte", "kiruna/ghost", live=False, recorded_hardware=True, target_hardware=True
    ),
    "target_unknown": Target(
        "kiruna/knatte", "kiruna/ghost", live=False, recorded_hardware=None, target_known=False
    ),
}


def test_a_simulated_recording_under_its_own_free_name_is_allowed() -> None:
    assert refusals(ALLOWED) == []


def test_a_real_platform_replayed_under_another_simulated_name_is_allowed() -> None:
    assert refusals(Target("kiruna/knatte", "kiruna/ghost", False, True, False)) == []


@pytest.mark.parametrize("row", [row for row, _, _ in REFUSALS])
def test_every_row_refuses_on_its_own(row: str) -> None:
    said = refusals(ONLY[row])
    assert [r for r, _ in said] == [row]
    assert "kiruna/" in said[0][1]


def test_every_row_that_applies_is_said() -> None:
    both = Target("kiruna/knatte", "kiruna/knatte", live=True, recorded_hardware=True)
    assert [r for r, _ in refusals(both)] == ["name_live", "own_name_real"]

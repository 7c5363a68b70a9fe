"""Frames and workspaces (agents/workspace.py): the common frame, the clamp, the hold."""

from __future__ import annotations

import math

import pytest

from agents.dynamics import SlopeField
from agents.gnc import CLOSED
from agents.guidance import Track
from agents.kinematic import KinematicPlatform
from agents.simulated import SimulatedPlatform
from agents.workspace import Area, Frame, FramedPlatform
from federation.core.wire import Pose
from schemas.platform import load_platform
from schemas.scenario import LabFrame

KNATTE = load_platform("knatte")


def test_knatte_area_is_the_camera_coverage_less_the_margin() -> None:
    assert KNATTE.table.width == 3.1 and KNATTE.table.height == 3.4
    assert Area.of(KNATTE) == Area(-1.35, 1.35, -0.7, 0.7)  # 3.0 x 1.7 m less 0.15 m


@pytest.mark.parametrize("deg", [0.0, 90.0, 180.0, -37.0])
def test_frame_round_trip(deg: float) -> None:
    frame = Frame.from_config(LabFrame(origin=(1.5, -2.0), rotation_deg=deg))
    pose = Pose(0.3, -0.4, 0.2, 0.01, 0.02, 0.03)
    back = frame.to_table(frame.to_common(pose))
    assert back == pytest.approx(pose, abs=1e-12)


def test_frame_rotates_a_quarter_turn() -> None:
    frame = Frame((1.0, 2.0), math.pi / 2)
    common = frame.to_common(Pose(1.0, 0.0, 0.0, 0.1, 0.0, 0.0))
    assert common == pytest.approx(Pose(1.0, 3.0, math.pi / 2, 0.0, 0.1, 0.0), abs=1e-12)


def test_a_reference_outside_the_area_is_clamped_and_counted() -> None:
    plat = FramedPlatform(KinematicPlatform(), Frame((10.0, 0.0)), Area(-1.0, 1.0, -0.5, 0.5))
    pose = plat.step(0.0, 0.0, 0.0, Track(10.0 + 3.0, 0.2, 0.1, 0.05))  # x 3 m out on its table
    assert (pose.x, pose.y) == pytest.approx((11.0, 0.2))  # on the edge, common frame
    assert (pose.vx, pose.vy) == pytest.approx((0.0, 0.05))  # the outward rate dropped
    assert plat.workspace_counters["workspace_clamped"] == 1
    plat.step(0.1, 0.0, 0.0, Track(10.5, 0.0))  # inside: not counted
    assert plat.workspace_counters["workspace_clamped"] == 1
    assert not plat.workspace_held


def _pushed_out(position_hold: bool, slope: float) -> FramedPlatform:
    """KNATTE 5 cm inside its area's +x edge on a table sloping down towards +x."""
    inner = SimulatedPlatform(KNATTE, seed=1, x=1.30, position_hold=position_hold)
    # One long sinusoid: a nearly uniform slope of ``slope`` down towards +x.
    k = 0.01
    inner.plant.field = SlopeField(((-slope / k, k, 0.0, 0.0),))
    plat = FramedPlatform(inner, Frame((0.0, 4.0)))
    for i in range(1500):
        plat.step(i * 0.01, 0.0, 0.0)
    return plat


def test_a_platform_pushed_out_by_the_slope_goes_to_safe_hold() -> None:
    plat = _pushed_out(position_hold=False, slope=0.0005)
    assert plat.workspace_held and plat.held
    assert plat.workspace_counters["workspace_holds"] == 1
    assert plat.valves == CLOSED
    assert plat.area_detail is not None and "left the area" in plat.area_detail
    truth = plat.truth  # common frame: the table is only shifted along y
    assert truth is not None and truth.x > 1.35  # it really is out
    plat.release()  # a link resuming does not release it
    assert plat.held
    plat.clear_workspace_hold()
    assert not plat.held


def test_a_platform_holding_its_position_stays_in() -> None:
    plat = _pushed_out(position_hold=True, slope=0.0005)
    assert not plat.workspace_held
    assert plat.workspace_counters["workspace_holds"] == 0
    truth = plat.truth
    assert truth is not None and truth.x < 1.35


def test_no_hold_before_the_first_fix() -> None:
    inner = SimulatedPlatform(KNATTE, x=5.0)  # outside the camera: no fix ever
    plat = FramedPlatform(inner, Frame())
    for i in range(50):
        plat.step(i * 0.01, 0.0, 0.0)
    assert not plat.workspace_held and plat.valves == CLOSED  # closed for want of a fix


def test_truth_is_in_the_common_frame() -> None:
    inner = SimulatedPlatform(KNATTE, x=0.2, y=0.1)
    plat = FramedPlatform(inner, Frame((1.0, 1.0), math.pi))
    truth = plat.truth
    assert truth is not None
    assert (truth.x, truth.y, truth.heading) == pytest.approx((0.8, 0.9, math.pi))

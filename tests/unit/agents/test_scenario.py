"""A scenario part and its guidance object (agents/scenario.py, schemas/scenario.py,
the experiment files under deploy/experiments/)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from agents.kinematic import KinematicPlatform
from agents.scenario import make_scenario
from agents.simulated import SimulatedPlatform
from agents.workspace import FramedPlatform
from federation.core.keys import AgentId
from federation.core.wire import Pose
from schemas.base import ConfigError, validate
from schemas.experiment import ExperimentConfig, load_experiment
from schemas.messages import Workspace
from schemas.platform import load_platform

EXPERIMENTS = Path("deploy/experiments")


def _spec(name: str) -> dict[str, Any]:
    return tomllib.loads((EXPERIMENTS / f"{name}.toml").read_text())


@pytest.mark.parametrize("name", ["attitude-tracking", "formation", "docking"])
def test_every_experiment_file_loads(name: str) -> None:
    load_experiment(EXPERIMENTS / f"{name}.toml")


def test_attitude_tracking_is_unchanged() -> None:
    e = load_experiment(EXPERIMENTS / "attitude-tracking.toml")
    assert e.kind == "attitude-tracking"
    assert e.part(AgentId("rome", "pinocchio")) is None  # the runtime runs as before


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: (s["participants"].pop(), s["frames"].pop("lab3")), "at least 3 platforms"),
        (lambda s: s["formation"]["slots"].pop("lab3/generic"), "no slot for lab3/generic"),
        (lambda s: s.pop("formation"), "needs a \\[formation\\] table"),
        (lambda s: s["frames"].update({"paris": {}}), "frames.paris"),
        (
            lambda s: (
                s["participants"][2].update({"agent": "rome/other"}),
                s["frames"].pop("lab3"),
            ),
            "one platform per lab",
        ),
    ],
)
def test_bad_formation_files_fail_naming_why(edit: Any, message: str) -> None:
    spec = _spec("formation")
    edit(spec)
    with pytest.raises(ConfigError, match=message):
        validate(ExperimentConfig, spec, "formation.toml")


def test_bad_docking_files_fail_naming_why() -> None:
    spec = _spec("docking")
    spec["frames"] = {"kiruna": {}}
    spec["participants"][1]["agent"] = "kiruna/chaser"
    spec["participants"][1]["follow"] = "kiruna/knatte"
    spec["docking"]["chaser"] = "kiruna/chaser"
    with pytest.raises(ConfigError, match="different labs"):
        validate(ExperimentConfig, spec, "docking.toml")
    spec = _spec("docking")
    spec["docking"]["contact"]["max_speed"] = 0.005
    with pytest.raises(ConfigError, match="final_speed"):
        validate(ExperimentConfig, spec, "docking.toml")


def test_formation_part_wraps_the_platform_in_its_lab_frame() -> None:
    e = load_experiment(EXPERIMENTS / "formation.toml")
    part = e.part(AgentId("rome", "pinocchio"))
    assert part is not None and part.kind == "formation"
    platform = SimulatedPlatform(load_platform("pinocchio"))
    g = make_scenario("rome/pinocchio", part, platform)
    assert isinstance(g.platform, FramedPlatform) and g.platform.inner is platform
    ref = g.reference(10.0, 0.0, {}, Pose())
    assert ref is not None and ref.track is not None
    assert (ref.track.x, ref.track.y) == pytest.approx((-3.5, -2.0))  # its slot, common frame
    pose = g.platform.step(0.0, ref.heading, ref.rate, ref.track)
    assert (pose.x, pose.y) == pytest.approx((-3.5, -2.0), abs=0.01)  # its table's centre
    assert g.fields()["x_ref"] == pytest.approx(-3.5)
    # What its status publishes for a view to draw: its lab's frame and its usable area.
    assert g.workspace() == Workspace(frame=part.frame, area=platform.config.usable_area)
    assert part.frame.origin == (-3.5, -2.0)


def test_docking_chaser_sees_the_target_only_through_its_sensor() -> None:
    e = load_experiment(EXPERIMENTS / "docking.toml")
    part = e.part(AgentId("rome", "pinocchio"))
    assert part is not None
    sensor = part.relative_sensor.model_copy(update={"dropout": 0.0})
    part = part.model_copy(update={"relative_sensor": sensor})
    g = make_scenario("rome/pinocchio", part, KinematicPlatform())
    own = g.platform.step(0.0, math.pi, 0.0)
    assert (own.x, own.y, own.heading) == pytest.approx((1.3, 0.1, math.pi))
    assert g.reference(1.0, 0.0, {}, own) is not None
    assert g.counters["relative_no_pose"] == 1
    g.reference(1.2, 0.2, {"kiruna/knatte": (1.2, Pose())}, own)
    assert g.counters["relative_given"] == 1
    assert g.fields()["phase"] == "approach"
    assert g.workspace() is None  # a kinematic platform has no area: none is kept or shown


def test_adaptive_gains_need_a_gnc_chain() -> None:
    spec = _spec("attitude-tracking")
    spec["participants"][1]["adaptive_gains"] = True
    e = validate(ExperimentConfig, spec, "attitude-tracking.toml")
    part = e.part(AgentId("rome", "pinocchio"))
    assert part is not None and part.adaptive is not None
    with pytest.raises(ValueError, match="GNC chain"):
        make_scenario("rome/pinocchio", part, KinematicPlatform(), follow="kiruna/knatte")
    platform = SimulatedPlatform(load_platform("pinocchio"))
    g = make_scenario("rome/pinocchio", part, platform, follow="kiruna/knatte")
    assert g.platform is platform  # attitude: no frame
    assert g.reference(1.0, 0.0, {"kiruna/knatte": (1.0, Pose(omega=0.2))}, Pose()) is None
    assert g.adaptive is not None and g.adaptive.scale > 1.0
    assert platform.chain.pid.kp > load_platform("pinocchio").control.kp

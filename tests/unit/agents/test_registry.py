"""Scenarios and platform kinds by name (agents/registry.py), shown with a scenario and a
platform kind defined outside the package (tests/plugins/): registered with one call,
checked at load with the file and the field, flown in rehearsal."""

from __future__ import annotations

import importlib
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from agents.interface import Platform
from agents.platform import make_platform
from agents.registry import (
    platform_names,
    register_platform,
    register_scenario,
    scenario_class,
    scenario_names,
)
from agents.rehearsal import rehearse
from agents.scenario import make_scenario
from agents.scenarios.formation import Formation
from agents.simulated import SimulatedPlatform
from agents.workspace import FramedPlatform
from federation.core.wire import Pose
from schemas.base import ConfigError, validate
from schemas.config import AgentConfig
from schemas.platform import PLATFORMS, load_platform
from schemas.registry import RegistryError
from schemas.scenario import SCENARIOS, ScenarioPart

PLUGINS = Path(__file__).resolve().parents[2] / "plugins"


def _plugin(monkeypatch: pytest.MonkeyPatch, module: str) -> Any:
    monkeypatch.syspath_prepend(str(PLUGINS))
    return importlib.import_module(module)


@pytest.fixture
def hold_point(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """tests/plugins/hold_point.py's scenario, registered for the test."""
    cls = _plugin(monkeypatch, "hold_point").HoldPoint
    assert register_scenario(cls) is cls
    try:
        yield cls
    finally:
        SCENARIOS.unregister("hold_point")


@pytest.fixture
def still(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """tests/plugins/still_platform.py's platform kind, registered for the test."""
    cls = _plugin(monkeypatch, "still_platform").StillPlatform
    assert register_platform(cls) is cls
    try:
        yield cls
    finally:
        PLATFORMS.unregister("still")


def _agent(**fields: Any) -> dict[str, Any]:
    return {"lab": "kiruna", "name": "knatte", "role": "leader", **fields}


def test_the_built_ins_are_listed_and_found() -> None:
    assert {"attitude-tracking", "formation", "docking"} <= set(scenario_names())
    assert {"kinematic", "simulated", "serial"} <= set(platform_names())
    assert scenario_class("formation") is Formation
    assert Formation.framed and Formation.watch_all and not scenario_class("docking").watch_all
    assert not scenario_class("attitude-tracking").framed


def test_a_scenario_from_outside_the_package_is_checked_at_load(hold_point: Any) -> None:
    assert "hold_point" in scenario_names() and scenario_class("hold_point") is hold_point
    scenario = {"kind": "hold_point", "settings": {"point": [0.3, -0.2]}}
    config = validate(AgentConfig, _agent(scenario=scenario), "knatte.toml")
    assert config.scenario is not None
    assert config.scenario.settings == hold_point.settings(point=(0.3, -0.2))
    # It round-trips (the agent command dumps an experiment's part and loads it again).
    again = validate(AgentConfig, config.model_dump(), "again")
    assert again.scenario == config.scenario
    default = ScenarioPart(kind="hold_point")  # no settings: the model's defaults
    assert default.settings == hold_point.settings()
    bad = {"kind": "hold_point", "settings": {"point": [0.3, "x"], "radius": 1}}
    with pytest.raises(ConfigError) as error:
        validate(AgentConfig, _agent(scenario=bad), "knatte.toml")
    assert "knatte.toml: field 'scenario.settings.point.1': Input should be a valid number" in (
        str(error.value)
    )
    assert "knatte.toml: field 'scenario.settings.radius': unknown field" in str(error.value)


@pytest.mark.parametrize(
    ("scenario", "message"),
    [
        (
            {"kind": "hold-point"},
            "field 'scenario.kind': Value error, unknown scenario 'hold-point' "
            r"\(known: attitude-tracking, docking, formation\)",
        ),
        ({"kind": "formation"}, "a formation part needs 'formation'"),
        ({"kind": "docking", "settings": {}}, "scenario 'docking' takes no settings"),
    ],
)
def test_a_scenario_part_that_cannot_be_flown_fails_at_load(
    scenario: dict[str, Any], message: str
) -> None:
    with pytest.raises(ConfigError, match=message):
        validate(AgentConfig, _agent(scenario=scenario), "knatte.toml")


def test_only_scenario_classes_register() -> None:
    with pytest.raises(RegistryError, match="not a Scenario subclass"):
        register_scenario(int)  # type: ignore[type-var]
    with pytest.raises(RegistryError, match="'formation' is built in"):
        register_scenario(type("Again", (Formation,), {}))


def test_the_scenario_flies_through_the_guidance_the_runtime_asks(hold_point: Any) -> None:
    part = ScenarioPart(kind="hold_point", settings={"point": (0.3, -0.2), "heading_deg": 90})
    platform = SimulatedPlatform(load_platform("knatte"))
    g = make_scenario("kiruna/knatte", part, platform)
    assert isinstance(g.platform, FramedPlatform) and g.platform.inner is platform
    assert isinstance(g.scenario, hold_point)
    ref = g.reference(1.0, 0.0, {}, Pose())
    assert ref is not None and ref.track is not None
    assert (ref.heading, ref.track.x, ref.track.y) == pytest.approx((math.pi / 2, 0.3, -0.2))
    assert g.counters == {"workspace_clamped": 0, "workspace_holds": 0, "hold_point_references": 1}
    assert g.fields() == {"x_ref": 0.3, "y_ref": -0.2}


def test_the_scenario_flies_in_rehearsal(hold_point: Any) -> None:
    part = ScenarioPart(kind="hold_point", settings={"point": (0.3, -0.2), "heading_deg": 30})
    run = rehearse({"kiruna/knatte": part}, {"kiruna/knatte": "knatte"}, duration=20.0)
    x, y, heading = run["series"]["truth"]["kiruna/knatte"][-1]
    assert math.hypot(x - 0.3, y + 0.2) < 0.02  # held at the point, on the truth
    assert math.degrees(heading) == pytest.approx(30.0, abs=1.0)
    assert run["series"]["x_ref"]["kiruna/knatte"][-1] == 0.3
    counters = run["counters"]["kiruna/knatte"]
    assert counters["hold_point_references"] > 0 and counters["workspace_holds"] == 0


def test_a_platform_kind_from_outside_the_package(still: Any) -> None:
    assert "still" in platform_names()
    config = validate(AgentConfig, _agent(platform="still:0.5,0.2"), "knatte.toml")
    assert not config.hardware
    platform = make_platform(config.platform, rate=10.0)
    assert isinstance(platform, still) and isinstance(platform, Platform)
    assert platform.step(0.0, 1.0, 0.0) == Pose(0.5, 0.2) and platform.rate == 10.0
    with pytest.raises(ConfigError, match=r"field 'platform': .*still:X,Y takes two numbers"):
        validate(AgentConfig, _agent(platform="still:here"), "knatte.toml")


def test_a_platform_spec_names_a_kind_or_a_preset() -> None:
    assert validate(AgentConfig, _agent(platform="serial:/dev/x", wait_start=True), "a").hardware
    with pytest.raises(ConfigError, match="serial platform needs a port"):
        validate(AgentConfig, _agent(platform="serial:"), "a")
    with pytest.raises(ConfigError, match="the kinematic platform takes no argument"):
        validate(AgentConfig, _agent(platform="kinematic:fast"), "a")
    with pytest.raises(
        ConfigError, match=r"unknown platform 'knatt'.*other choices: kinematic, serial:PORT"
    ):
        validate(AgentConfig, _agent(platform="knatt"), "a")
    with pytest.raises(ConfigError, match="a real platform flies only runs an operator starts"):
        validate(AgentConfig, _agent(platform="serial:/dev/x"), "a")
    with pytest.raises(ConfigError, match="platform_preset applies to a real platform"):
        validate(AgentConfig, _agent(platform="knatte", platform_preset="knatte"), "a")
    with pytest.raises(ConfigError, match="'kinematic' is not a preset"):
        validate(
            AgentConfig,
            _agent(platform="serial:/dev/x", wait_start=True, platform_preset="kinematic"),
            "a",
        )

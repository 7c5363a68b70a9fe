"""Scenario settings beyond attitude: lab frames, formation, docking, the relative sensor
and adaptive gains, and the registry of scenarios by name.

An experiment file (:mod:`schemas.experiment`) holds them; each agent gets its own part,
a :class:`ScenarioPart`, in its :class:`~schemas.config.AgentConfig`
(``fedlab agent --experiment FILE`` fills it in). Units are in every field's description.

Scenarios are found by name in :data:`SCENARIOS`: the built-ins (``attitude-tracking``,
``formation``, ``docking``) and any a plug-in registers
(:func:`agents.registry.register_scenario`, or a ``fedlab.scenarios`` entry point). A
part's ``kind`` must name one, and its ``settings`` are validated by that scenario's
config model at load: a bad value fails with the file and the field.

Frames: every lab's table has its own frame (x, y on the table, heading from its x
axis); a lab declares where that frame sits in the federation's common frame
(:class:`LabFrame`). Poses on the wire are in the common frame.

Rule: imports :mod:`schemas.base` and :mod:`schemas.registry` only, so
:mod:`schemas.config` and :mod:`schemas.experiment` can both build on it.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Protocol, runtime_checkable

from pydantic import (
    AfterValidator,
    Field,
    SerializeAsAny,
    ValidationInfo,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from schemas.base import Model
from schemas.registry import Registry

__all__ = [
    "SCENARIOS",
    "AdaptiveConfig",
    "ContactCriteria",
    "DockingConfig",
    "FormationConfig",
    "LabFrame",
    "RelativeSensorConfig",
    "ScenarioEntry",
    "ScenarioKind",
    "ScenarioPart",
]


@runtime_checkable
class ScenarioEntry(Protocol):
    """What configuration reads of a registered scenario (a subclass of
    :class:`agents.scenarios.Scenario`)."""

    @property
    def name(self) -> str:
        """The scenario's name, as ``kind`` gives it."""
        ...

    @property
    def settings(self) -> type[Model] | None:
        """The config model of a part's ``settings``; None: the scenario takes none."""
        ...

    def check_part(self, part: ScenarioPart) -> None:
        """What a part of this scenario needs beyond its settings (a built-in's table);
        ValueError saying what is missing."""
        ...


def _accept_scenario(name: str, obj: object) -> ScenarioEntry:
    if not isinstance(obj, type) or not isinstance(obj, ScenarioEntry):
        raise TypeError(f"{obj!r} is not a scenario class with name, settings and check_part")
    if obj.name != name:
        raise TypeError(f"{obj.__qualname__} says its name is {obj.name!r}")
    settings = obj.settings
    if settings is not None and not (isinstance(settings, type) and issubclass(settings, Model)):
        raise TypeError(f"its settings {settings!r} are not a config model (schemas.base.Model)")
    return obj


SCENARIOS: Registry[ScenarioEntry] = Registry(
    "scenario",
    "fedlab.scenarios",
    {
        "attitude-tracking": "agents.scenarios.attitude:AttitudeTracking",
        "formation": "agents.scenarios.formation:Formation",
        "docking": "agents.scenarios.docking:Docking",
    },
    _accept_scenario,
)
"""Scenarios by name: the built-ins and any a plug-in registers."""


def _registered(kind: str) -> str:
    SCENARIOS.get(kind)  # a RegistryError (a ValueError) names what is wrong
    return kind


ScenarioKind = Annotated[str, AfterValidator(_registered)]
"""What an experiment rehearses: the name of a registered scenario
(``attitude-tracking``, ``formation``, ``docking`` or a plug-in's)."""

Vec2 = tuple[float, float]


class LabFrame(Model):
    """Where a lab's table frame sits in the common frame:
    :math:`p_c = R(\\theta) p_t + o`, :math:`\\psi_c = \\psi_t + \\theta`."""

    origin: Vec2 = Field(
        (0.0, 0.0), description="the table frame's origin in the common frame (x, y), m"
    )
    rotation_deg: float = Field(
        0.0, ge=-180, le=180, description="the table's x axis from the common x axis, degrees"
    )


class RelativeSensorConfig(Model):
    """An emulated relative sensor (paper section 3.2) on the body's +x axis: range,
    bearing and relative heading of another platform, with noise growing with range."""

    rate: float = Field(10.0, gt=0, le=1000, description="measurements per second, Hz")
    range_noise: float = Field(0.002, ge=0, description="range noise at zero range, 1 sigma, m")
    range_noise_per_m: float = Field(
        0.004, ge=0, description="range noise growth, 1 sigma, m per m of range"
    )
    bearing_noise_deg: float = Field(
        0.1, ge=0, description="bearing noise at zero range, 1 sigma, degrees"
    )
    bearing_noise_per_m_deg: float = Field(
        0.1, ge=0, description="bearing noise growth, 1 sigma, degrees per m of range"
    )
    heading_noise_deg: float = Field(
        0.2, ge=0, description="relative heading noise, 1 sigma, degrees"
    )
    fov_deg: float = Field(
        60.0, gt=0, le=360, description="field of view, full angle about the body x axis, degrees"
    )
    max_range: float = Field(4.0, gt=0, description="largest range measured, m")
    dropout: float = Field(
        0.02, ge=0, lt=1, description="probability that a due measurement is lost"
    )
    horizon: float = Field(
        1.0, gt=0, le=10, description="longest dead reckoning of the other's shared pose, s"
    )
    seed: int = Field(0, ge=0, description="seed of the noise and dropouts")


MAX_PATH_SPEED = 0.5
"""m/s: the fastest a formation's centre may move (docking's speeds are capped alike)."""
MAX_PATH_ACCEL = 0.5
"""m/s^2: the largest acceleration a formation's centre may ask (several times what a
platform's thrusters give)."""


class FormationConfig(Model):
    """N platforms keep slots around a virtual centre that follows a circle:

    .. math::

        c(t) = c_0 + R(\\cos\\theta(t) - 1,\\ \\sin\\theta(t)), \\qquad
        \\dot\\theta = 2\\pi / T \\text{ after a ramp of } T_r

    Each agent's reference is its slot around a blend of the path's centre and the
    centre implied by the others' shared poses (decentralized consensus)."""

    centre: Vec2 = Field((0.0, 0.0), description="the virtual centre at the start, common frame, m")
    radius: float = Field(0.4, ge=0, description="radius of the centre's circle, m")
    period: float = Field(50.0, gt=0, description="seconds per turn of the circle")
    still: float = Field(5.0, ge=0, description="seconds still after the start")
    ramp: float = Field(10.0, gt=0, description="seconds to reach the circle's speed")
    heading_deg: float = Field(0.0, ge=-180, le=180, description="every member's heading, degrees")
    consensus_weight: float = Field(
        0.7,
        ge=0,
        lt=1,
        description="share of the centre estimate taken from the others' shared poses",
    )
    stale_after: float = Field(
        1.0, gt=0, le=10, description="seconds after which another's pose is left out"
    )
    join_ramp: float = Field(
        2.0,
        gt=0,
        le=60,
        description="seconds over which another's pose is taken in after it appears "
        "(its weight fades out alike over the last half of stale_after)",
    )
    slots: dict[str, Vec2] = Field(
        default_factory=dict,
        description="LAB/NAME -> slot offset from the virtual centre, common frame, m",
    )

    @model_validator(mode="after")
    def _feasible(self) -> FormationConfig:
        # As docking's speeds: a path no air-bearing platform can fly is a typo (a period
        # of 0.5 s asks 5 m/s and 63 m/s^2), and the valves would saturate chasing it.
        speed = 2.0 * math.pi * self.radius / self.period
        accel = max(speed * speed / self.radius if self.radius else 0.0, speed / self.ramp)
        if speed > MAX_PATH_SPEED:
            raise ValueError(
                f"the centre would move at {speed:.3g} m/s (2 pi radius / period), over "
                f"{MAX_PATH_SPEED} m/s: a longer period or a smaller radius"
            )
        if accel > MAX_PATH_ACCEL:
            raise ValueError(
                f"the centre would accelerate at {accel:.3g} m/s^2 (on the circle or in "
                f"the ramp), over {MAX_PATH_ACCEL} m/s^2: a longer period or ramp"
            )
        return self


class ContactCriteria(Model):
    """When a contact counts as a successful docking (on the relative truth)."""

    max_speed: float = Field(0.02, gt=0, description="largest closing speed, m/s")
    max_lateral: float = Field(0.02, gt=0, description="largest lateral offset, m")
    max_heading_deg: float = Field(2.0, gt=0, description="largest heading error, degrees")


class DockingConfig(Model):
    """A chaser docks on a target's port (the target's body +x axis) from emulated
    relative measurements alone: approach, hold point, final approach, contact."""

    target: str = Field(description="LAB/NAME of the target")
    chaser: str = Field(description="LAB/NAME of the chaser")
    contact_distance: float = Field(
        0.5, gt=0, description="centre-to-centre distance at contact along the axis, m"
    )
    hold_distance: float = Field(
        0.3, gt=0, description="the hold point's distance beyond contact along the axis, m"
    )
    hold_time: float = Field(8.0, ge=0, description="seconds settled at the hold point", le=600)
    hold_tolerance: float = Field(
        0.01, gt=0, description="position error at the hold point that counts as settled, m"
    )
    approach_speed: float = Field(0.03, gt=0, le=0.5, description="approach speed, m/s")
    final_speed: float = Field(0.01, gt=0, le=0.5, description="final approach speed, m/s")
    corridor_deg: float = Field(
        15.0, gt=0, lt=90, description="approach corridor half-angle about the axis, degrees"
    )
    lost_after: float = Field(
        2.0, gt=0, le=60, description="seconds without a measurement before backing off, s"
    )
    target_rate_deg: float = Field(
        0.0, ge=-10, le=10, description="the target's constant heading rate, degrees/s"
    )
    target_drift: Vec2 = Field(
        (0.0, 0.0), description="the target's constant drift velocity, common frame, m/s"
    )
    contact: ContactCriteria = Field(default_factory=ContactCriteria)

    @model_validator(mode="after")
    def _speeds(self) -> DockingConfig:
        if self.final_speed >= self.contact.max_speed:
            raise ValueError(
                f"final_speed ({self.final_speed} m/s) must be below the contact criterion "
                f"({self.contact.max_speed} m/s)"
            )
        if self.target == self.chaser:
            raise ValueError("the chaser cannot dock with itself")
        return self


class AdaptiveConfig(Model):
    """A follower's gain schedule from the leader's dynamic range it observes:

    .. math::

        s = \\mathrm{clip}(\\hat\\omega_{peak} / \\omega_{nominal}, 1, s_{max}), \\quad
        K_p' = s^2 K_p, \\quad K_d' = s K_d, \\quad K_i' = s^3 K_i

    (the closed loop's natural frequency scales with :math:`s`, its damping stays)."""

    nominal_rate_deg: float = Field(
        3.0,
        gt=0,
        description="leader's peak heading rate the preset's gains are tuned for, deg/s "
        "(the paper's maneuver peaks at 2.4, its estimate's noise on top)",
    )
    max_scale: float = Field(2.5, ge=1, le=10, description="largest frequency scale s")
    window: float = Field(20.0, gt=0, le=600, description="seconds of received samples watched")


class ScenarioPart(Model):
    """One agent's part of a scenario (filled in from the experiment file)."""

    kind: ScenarioKind = Field(
        "attitude-tracking",
        description="the scenario: attitude-tracking, formation, docking or a plug-in's",
    )
    frame: LabFrame = Field(default_factory=LabFrame, description="this lab's table frame")
    formation: FormationConfig | None = None
    docking: DockingConfig | None = None
    relative_sensor: RelativeSensorConfig = Field(default_factory=RelativeSensorConfig)
    adaptive: AdaptiveConfig | None = Field(
        None, description="schedule the heading gains from the leader's dynamic range"
    )
    settings: (
        Annotated[
            SerializeAsAny[Model],
            WithJsonSchema({"type": "object", "description": "fields of the scenario's model"}),
        ]
        | None
    ) = Field(
        None,
        validate_default=True,
        description="the scenario's own settings, validated by its config model (a "
        "plug-in's); none for the built-ins, whose settings are the tables above",
    )

    @field_validator("settings", mode="before")
    @classmethod
    def _settings(cls, value: Any, info: ValidationInfo) -> Any:
        kind = info.data.get("kind")
        if kind is None:  # the kind did not validate: its error says why
            return None
        model = SCENARIOS.get(kind).settings
        if model is None:
            if value is not None:
                raise ValueError(f"scenario {kind!r} takes no settings")
            return None
        if isinstance(value, model):
            return value
        if isinstance(value, Model):
            value = value.model_dump()
        return model.model_validate({} if value is None else value)

    @model_validator(mode="after")
    def _kind(self) -> ScenarioPart:
        SCENARIOS.get(self.kind).check_part(self)
        return self

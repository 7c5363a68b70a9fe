"""A scenario defined outside the fedlab package: ``hold_point``, each platform holds one
fixed point of the common frame at one heading.

All a new scenario takes: this module (its config model and its :class:`Scenario`
subclass) and one registration, either in code::

    from agents.registry import register_scenario
    register_scenario(HoldPoint)

or, for an installed distribution, an entry point (pyproject.toml)::

    [project.entry-points."fedlab.scenarios"]
    hold_point = "hold_point:HoldPoint"

An agent then flies it from its configuration::

    [scenario]
    kind = "hold_point"
    [scenario.settings]
    point = [0.3, -0.2]
"""

from __future__ import annotations

import math

from pydantic import Field

from agents.guidance import Reference, Track
from agents.interface import Platform
from agents.scenarios import Others, Scenario
from federation.core.wire import Pose
from schemas.base import Model
from schemas.scenario import ScenarioPart

__all__ = ["HoldPoint", "HoldPointSettings"]


class HoldPointSettings(Model):
    """Where the platform holds."""

    point: tuple[float, float] = Field((0.0, 0.0), description="the point, common frame, m")
    heading_deg: float = Field(0.0, ge=-180, le=180, description="the heading held, degrees")


class HoldPoint(Scenario):
    """The point and heading of the settings, from the start (no run needed)."""

    name = "hold_point"
    settings = HoldPointSettings
    framed = True

    def __init__(
        self,
        me: str,
        part: ScenarioPart,
        platform: Platform,
        follow: str | None = None,
        compensate: bool = True,
    ):
        super().__init__(me, part, platform, follow, compensate)
        assert isinstance(part.settings, HoldPointSettings)  # validated at load
        x, y = part.settings.point
        self.target = Reference(math.radians(part.settings.heading_deg), 0.0, Track(x, y))
        self.given = 0

    def reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        self.given += 1
        return self.target

    @property
    def counters(self) -> dict[str, int]:
        return {"hold_point_references": self.given}

"""``docking``: a chaser docks with a target in another lab from emulated relative
measurements (``part.docking``, ``part.relative_sensor``). The chaser flies
:class:`~agents.docking.DockingGuidance`; the target
:class:`~agents.docking.TargetGuidance` (its constant drift and turn)."""

from __future__ import annotations

from agents.docking import DockingGuidance, TargetGuidance
from agents.guidance import Reference
from agents.interface import Platform
from agents.scenarios.base import Others, Scenario
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import ScenarioPart

__all__ = ["Docking"]


class Docking(Scenario):
    """The chaser's or the target's part, by ``me`` (ValueError for any other agent)."""

    name = "docking"
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
        d = part.docking
        assert d is not None  # check_part, at load
        self.config = d
        self.chaser: DockingGuidance | None = None
        self.target: TargetGuidance | None = None
        if me == d.chaser:
            self.chaser = DockingGuidance(d, part.relative_sensor, compensate)
        elif me == d.target:
            self.target = TargetGuidance(d)
        else:
            raise ValueError(f"{me} is neither the chaser nor the target of the docking")

    @classmethod
    def check_part(cls, part: ScenarioPart) -> None:
        if part.docking is None:
            raise ValueError("a docking part needs 'docking'")

    def new_run(self) -> None:
        """The chaser's phase, point and target estimate, the target's start, afresh."""
        if self.chaser is not None:
            self.chaser.new_run()
        if self.target is not None:
            self.target.new_run()

    def reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        if not self.platform.has_fix:
            # Valves are closed without a fix: nothing to steer, and the estimate is
            # only the filter's prior, not a heading to keep.
            return Reference(own.heading, 0.0, None)
        if self.chaser is not None:
            # The chaser sees the target only through its emulated relative sensor.
            return self.chaser.reference(t, run_time, others.get(self.config.target), own, frozen)
        assert self.target is not None
        return self.target.reference(run_time, own, frozen)

    @property
    def counters(self) -> dict[Count, int]:
        """The chaser's relative sensor's (``relative_*``) and its guidance's."""
        if self.chaser is None:
            return {}
        return self.chaser.sensor.counters | self.chaser.counters

    def fields(self) -> dict[str, float | str | None]:
        """The chaser's phase."""
        return {} if self.chaser is None else {"phase": self.chaser.phase}

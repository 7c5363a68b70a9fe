"""``formation``: N platforms in N labs keep their slots around a virtual centre that
circles (:class:`~agents.formation.FormationGuidance`, from ``part.formation``), each
from every other member's shared pose."""

from __future__ import annotations

from agents.formation import FormationGuidance
from agents.guidance import Reference
from agents.interface import Platform
from agents.scenarios.base import Others, Scenario
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import ScenarioPart

__all__ = ["Formation"]


class Formation(Scenario):
    """A member's slot around the path's centre and the centre the others imply."""

    name = "formation"
    framed = True
    watch_all = True

    def __init__(
        self,
        me: str,
        part: ScenarioPart,
        platform: Platform,
        follow: str | None = None,
        compensate: bool = True,
    ):
        super().__init__(me, part, platform, follow, compensate)
        assert part.formation is not None  # check_part, at load
        self.guidance = FormationGuidance(me, part.formation, compensate)

    @classmethod
    def check_part(cls, part: ScenarioPart) -> None:
        if part.formation is None:
            raise ValueError("a formation part needs 'formation'")

    def new_run(self) -> None:
        self.guidance.new_run()

    def reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        return self.guidance.reference(t, run_time, others, frozen)

    @property
    def counters(self) -> dict[Count, int]:
        return dict(self.guidance.counters)

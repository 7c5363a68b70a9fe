"""``attitude-tracking``: the paper's experiment. The leader flies its maneuver and
followers track the heading they receive, both by the runtime's own heading guidance:
this scenario gives no reference of its own (a follower's adaptive gains, if any, are
the :class:`~agents.scenario.ScenarioGuidance`'s, as for any scenario)."""

from __future__ import annotations

from agents.guidance import Reference
from agents.scenarios.base import Others, Scenario
from federation.core.wire import Pose

__all__ = ["AttitudeTracking"]


class AttitudeTracking(Scenario):
    """The runtime's heading guidance: no reference of its own."""

    name = "attitude-tracking"

    def reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        return None

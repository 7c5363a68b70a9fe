"""One agent's part of a scenario: the guidance object the agent runtime asks for its
3-DOF reference, and the platform seen in the common frame.

:func:`make_scenario` builds a :class:`ScenarioGuidance` from the agent's
:class:`~schemas.scenario.ScenarioPart`: the scenario its ``kind`` names, found in the
registry (:func:`agents.registry.scenario_class`; one module per scenario under
:mod:`agents.scenarios`, or a plug-in's). The runtime then, every control step,

1. steps :attr:`ScenarioGuidance.platform` (a :class:`~agents.workspace.FramedPlatform`
   for a framed scenario, as formation and docking: common frame in and out, the lab's
   area kept) instead of its own platform;
2. asks :meth:`ScenarioGuidance.reference` for the reference, giving reference time,
   run time, every other agent's latest shared pose stamped on reference time (its
   clock mapped with the sync estimates) and its own estimate.

A None reference means: the runtime's own heading guidance (attitude tracking, where
only the gains adapt). Adaptive gains (``part.adaptive``) schedule the platform's
heading gains from the followed agent's samples, whatever the scenario. Pure: no I/O,
no clock.
"""

from __future__ import annotations

from agents.adaptive import AdaptiveGains
from agents.guidance import Reference
from agents.interface import Platform
from agents.registry import scenario_class
from agents.scenarios.base import Others, Scenario
from agents.workspace import Frame, FramedPlatform
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.messages import Workspace
from schemas.scenario import ScenarioPart

__all__ = ["Others", "ScenarioGuidance", "make_scenario"]


class ScenarioGuidance:
    """What one agent does in a scenario (see the module's docstring).

    Parameters
    ----------
    me : str
        This agent, ``LAB/NAME``.
    part : ScenarioPart
        Its part (kind, lab frame, scenario settings).
    platform : Platform
        Its platform, table frame.
    follow : str, optional
        The agent a follower tracks (adaptive gains watch its samples).
    compensate : bool
        Dead-reckon the others' shared poses to now (latency compensation).

    Raises
    ------
    ValueError
        A part this agent cannot fly (adaptive gains without a heading controller, an
        agent that has no role in the docking, ...), or a kind that is not registered
        (a :class:`~schemas.registry.RegistryError`).
    """

    def __init__(
        self,
        me: str,
        part: ScenarioPart,
        platform: Platform,
        follow: str | None = None,
        compensate: bool = True,
    ):
        self.me = me
        self.part = part
        self.kind = part.kind
        self.follow = follow
        cls = scenario_class(part.kind)
        self.platform: Platform = platform
        if cls.framed:
            self.platform = FramedPlatform(platform, Frame.from_config(part.frame))
        self.scenario: Scenario = cls(me, part, self.platform, follow, compensate)
        """The scenario's own guidance for this agent."""
        self.adaptive: AdaptiveGains | None = None
        if part.adaptive is not None:
            pid = platform.heading_pid
            if pid is None:
                kind = type(platform).__name__
                raise ValueError(f"adaptive gains need a platform with a GNC chain, not {kind}")
            self.adaptive = AdaptiveGains(part.adaptive, pid)
        self.last: Reference | None = None
        """The last reference given."""

    def new_run(self) -> None:
        """A run was armed: what one run's guidance keeps (the docking's phase, point and
        target estimate, the target's start, the formation members' ramps) begins afresh."""
        self.scenario.new_run()

    def reference(
        self,
        t: float | None,
        run_time: float | None,
        others: Others,
        own: Pose,
        frozen: bool = False,
    ) -> Reference | None:
        """The reference at reference time ``t`` and run time ``run_time`` (s; None
        before sync or before the start); None: use the runtime's heading guidance.
        ``frozen``: the run is paused (the reference stands still)."""
        if self.adaptive is not None and self.follow is not None:
            sample = others.get(self.follow)
            if sample is not None:
                self.adaptive.observe(sample[0], sample[1].omega)
        self.last = self.scenario.reference(t, run_time, others, own, frozen)
        return self.last

    @property
    def workspace_held(self) -> bool:
        """Whether the platform left its area and is held for it."""
        return isinstance(self.platform, FramedPlatform) and self.platform.workspace_held

    @property
    def area_detail(self) -> str | None:
        """Where the platform left its area, while :attr:`workspace_held` (free text)."""
        return self.platform.area_detail if isinstance(self.platform, FramedPlatform) else None

    def workspace(self) -> Workspace | None:
        """The lab's frame and the area the platform is kept in, as the status publishes
        them (None: no area is kept)."""
        area = self.platform.area if isinstance(self.platform, FramedPlatform) else None
        if area is None:
            return None
        return Workspace(
            frame=self.part.frame, area=(area.x_min, area.x_max, area.y_min, area.y_max)
        )

    def fields(self) -> dict[str, float | str | None]:
        """What the agent records beside its heading reference: the position reference
        (common frame, m), the scenario's own (the docking phase), the adaptive gains'
        scale."""
        out: dict[str, float | str | None] = {}
        track = None if self.last is None else self.last.track
        out["x_ref"] = None if track is None else track.x
        out["y_ref"] = None if track is None else track.y
        out |= self.scenario.fields()
        if self.adaptive is not None:
            out["gain_scale"] = self.adaptive.scale
        return out

    @property
    def counters(self) -> dict[Count, int]:
        """Workspace counters and the scenario's (relative sensing, docking, formation)."""
        out: dict[Count, int] = {}
        if isinstance(self.platform, FramedPlatform):
            out |= self.platform.workspace_counters
        return out | self.scenario.counters


def make_scenario(
    me: str,
    part: ScenarioPart,
    platform: Platform,
    follow: str | None = None,
    compensate: bool = True,
) -> ScenarioGuidance:
    """The agent's :class:`ScenarioGuidance` (raises ValueError for a part it cannot fly)."""
    return ScenarioGuidance(me, part, platform, follow, compensate)

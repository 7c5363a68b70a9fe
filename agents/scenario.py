"""One agent's part of a scenario: the guidance object the agent runtime asks for its
3-DOF reference, and the platform seen in the common frame.

:func:`make_scenario` builds a :class:`ScenarioGuidance` from the agent's
:class:`~schemas.scenario.ScenarioPart`; the runtime then, every control step,

1. steps :attr:`ScenarioGuidance.platform` (a :class:`~agents.workspace.FramedPlatform`
   for formation and docking: common frame in and out, the lab's area kept) instead of
   its own platform;
2. asks :meth:`ScenarioGuidance.reference` for the reference, giving reference time,
   run time, every other agent's latest shared pose stamped on reference time (its
   clock mapped with the sync estimates) and its own estimate.

A None reference means: the runtime's own heading guidance (attitude tracking, where
only the gains adapt). Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections.abc import Mapping

from agents.adaptive import AdaptiveGains
from agents.docking import DockingGuidance, TargetGuidance
from agents.formation import FormationGuidance
from agents.gnc import GncChain
from agents.guidance import Reference
from agents.interface import Platform
from agents.workspace import Frame, FramedPlatform
from federation.core.wire import Pose
from schemas.messages import Workspace
from schemas.scenario import ScenarioPart

__all__ = ["ScenarioGuidance", "make_scenario"]

Others = Mapping[str, tuple[float, Pose]]
"""LAB/NAME -> (stamp on reference time, s; shared pose, common frame)."""


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
        self.formation: FormationGuidance | None = None
        self.docking: DockingGuidance | None = None
        self.target: TargetGuidance | None = None
        self.adaptive: AdaptiveGains | None = None
        self.platform: Platform = platform
        self.last: Reference | None = None
        """The last reference given."""
        if part.kind in ("formation", "docking"):
            self.platform = FramedPlatform(platform, Frame.from_config(part.frame))
        if part.kind == "formation":
            assert part.formation is not None  # the part's validator
            self.formation = FormationGuidance(me, part.formation, compensate)
        elif part.kind == "docking":
            d = part.docking
            assert d is not None
            if me == d.chaser:
                self.docking = DockingGuidance(d, part.relative_sensor, compensate)
            elif me == d.target:
                self.target = TargetGuidance(d)
            else:
                raise ValueError(f"{me} is neither the chaser nor the target of the docking")
        if part.adaptive is not None:
            chain = getattr(platform, "chain", None)
            if not isinstance(chain, GncChain):
                kind = type(platform).__name__
                raise ValueError(f"adaptive gains need a platform with a GNC chain, not {kind}")
            self.adaptive = AdaptiveGains(part.adaptive, chain.pid)

    def new_run(self) -> None:
        """A run was armed: what one run's guidance keeps (the docking's phase, point and
        target estimate, the target's start, the formation members' ramps) begins afresh."""
        if self.docking is not None:
            self.docking.new_run()
        if self.target is not None:
            self.target.new_run()
        if self.formation is not None:
            self.formation.new_run()

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
        self.last = self._reference(t, run_time, others, own, frozen)
        return self.last

    def _reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        if self.adaptive is not None and self.follow is not None:
            sample = others.get(self.follow)
            if sample is not None:
                self.adaptive.observe(sample[0], sample[1].omega)
        if self.formation is not None:
            return self.formation.reference(t, run_time, others, frozen)
        if isinstance(self.platform, FramedPlatform) and not self.platform.has_fix:
            # Valves are closed without a fix: nothing to steer, and the estimate is
            # only the filter's prior, not a heading to keep.
            return Reference(own.heading, 0.0, None)
        if self.docking is not None:
            assert self.part.docking is not None
            # The chaser sees the target only through its emulated relative sensor.
            target = others.get(self.part.docking.target)
            return self.docking.reference(t, run_time, target, own, frozen)
        if self.target is not None:
            return self.target.reference(run_time, own, frozen)
        return None

    @property
    def workspace_held(self) -> bool:
        """Whether the platform left its area and is held for it."""
        return isinstance(self.platform, FramedPlatform) and self.platform.workspace_held

    @property
    def hold_reason(self) -> str | None:
        return self.platform.hold_reason if isinstance(self.platform, FramedPlatform) else None

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
        (common frame, m), the docking phase, the adaptive gains' scale."""
        out: dict[str, float | str | None] = {}
        track = None if self.last is None else self.last.track
        out["x_ref"] = None if track is None else track.x
        out["y_ref"] = None if track is None else track.y
        if self.docking is not None:
            out["phase"] = self.docking.phase
        if self.adaptive is not None:
            out["gain_scale"] = self.adaptive.scale
        return out

    @property
    def counters(self) -> dict[str, int]:
        """Workspace, sensor, docking and formation counters."""
        out: dict[str, int] = {}
        if isinstance(self.platform, FramedPlatform):
            out |= self.platform.workspace_counters
        if self.docking is not None:
            out |= {f"relative_{k}": v for k, v in self.docking.sensor.counters.items()}
            out |= self.docking.counters
        if self.formation is not None:
            out |= self.formation.counters
        return out


def make_scenario(
    me: str,
    part: ScenarioPart,
    platform: Platform,
    follow: str | None = None,
    compensate: bool = True,
) -> ScenarioGuidance:
    """The agent's :class:`ScenarioGuidance` (raises ValueError for a part it cannot fly)."""
    return ScenarioGuidance(me, part, platform, follow, compensate)

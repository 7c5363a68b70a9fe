"""What every part of an agent may ask of the agent itself: who it is, its clock and
session, and where it counts, logs and records. The parts depend on this and on each
other in one direction (recordings and peers first, then the run, the intake, the
watches, the reporter); only the facade (:mod:`federation.runtime.agent.runtime`)
knows them all."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import zenoh

    from agents.guidance import Track
    from agents.interface import Platform
    from agents.scenario import ScenarioGuidance
    from federation.core import wire
    from federation.core.channels import Channel
    from federation.core.counters import Count
    from federation.core.keys import AgentId
    from federation.core.timebase import TimeBase
    from federation.runtime.clock import ExecClock
    from federation.runtime.fanout import Fanout
    from federation.runtime.links import SyncLinks
    from federation.runtime.recorder import Message
    from federation.runtime.safety import Safety
    from schemas.config import AgentConfig
    from schemas.messages import Readiness, Status

__all__ = ["AgentServices"]


class AgentServices(Protocol):
    """The agent as its parts see it."""

    me: AgentId
    follow: AgentId | None
    reference: AgentId
    ref_id: int
    clock: ExecClock
    session: zenoh.Session
    links: SyncLinks
    fanout: Fanout | None
    platform: Platform
    scenario: ScenarioGuidance | None
    safety: Safety
    timebase: TimeBase[AgentId]
    pose: wire.Pose
    guidance: tuple[float, float]
    track: Track | None
    """The position reference the platform flies this step (common frame; None: none)."""
    maneuver: Callable[[float], tuple[float, float]]

    @property
    def config(self) -> AgentConfig: ...

    def key(self, agent: AgentId, topic: str | None = None) -> str: ...

    def count(self, name: Count) -> None: ...

    def reject(self, kind: str, message: str) -> None: ...

    def recording(self, topic: Channel) -> bool: ...

    def record(self, topic: Channel, message: Message) -> None: ...

    def event(self, kind: str, t_exec: float, host: float, detail: str) -> None: ...

    def sim_time(self, t_exec: float) -> float | None: ...

    def others(self) -> dict[str, tuple[float, wire.Pose]]: ...

    def status(self) -> Status: ...

    def readiness(self, t_exec: float) -> Readiness: ...

    def counter_snapshot(self) -> dict[Count, int]: ...

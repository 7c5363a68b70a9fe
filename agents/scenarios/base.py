"""What a scenario is: :class:`Scenario`, one agent's part of it, asked for a reference
every control step.

The agent runtime (through :class:`agents.scenario.ScenarioGuidance`) builds one
instance per agent from the agent's :class:`~schemas.scenario.ScenarioPart` and, every
control step, asks :meth:`Scenario.reference` for its 3-DOF reference, giving reference
time, run time, every other agent's latest shared pose stamped on reference time and
its own estimate. What the class states, the runtime does:

- ``name``: the scenario's name, as a part's ``kind`` and an experiment's give it;
- ``settings``: the config model of a part's ``settings`` (validated at load, so a bad
  value fails with the file and the field); None: it takes none;
- ``framed``: it flies in the common frame, the platform kept in its lab's area
  (:class:`~agents.workspace.FramedPlatform`, the part's ``frame``);
- ``watch_all``: it reads every other agent's pose, not only the followed one's.

Pure: no I/O, no clock.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

from agents.guidance import Reference
from agents.interface import Platform
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.base import Model
from schemas.scenario import ScenarioPart

__all__ = ["Others", "Scenario"]

Others = Mapping[str, tuple[float, Pose]]
"""LAB/NAME -> (stamp on reference time, s; shared pose, common frame)."""


class Scenario(ABC):
    """One agent's part of a scenario (see the module's docstring).

    Parameters
    ----------
    me : str
        This agent, ``LAB/NAME``.
    part : ScenarioPart
        Its part: kind, lab frame, the scenario's settings (``part.settings``, an
        instance of :attr:`settings`).
    platform : Platform
        Its platform: a :class:`~agents.workspace.FramedPlatform` (common frame) for a
        framed scenario.
    follow : str, optional
        The agent it follows, if any.
    compensate : bool
        Dead-reckon the others' shared poses to now (latency compensation).
    """

    name: ClassVar[str]
    settings: ClassVar[type[Model] | None] = None
    framed: ClassVar[bool] = False
    watch_all: ClassVar[bool] = False

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
        self.platform = platform
        self.follow = follow
        self.compensate = compensate

    @classmethod
    def check_part(cls, part: ScenarioPart) -> None:
        """What a part needs beyond its settings (ValueError if missing): nothing."""
        return None

    @abstractmethod
    def reference(
        self, t: float | None, run_time: float | None, others: Others, own: Pose, frozen: bool
    ) -> Reference | None:
        """The reference at reference time ``t`` and run time ``run_time`` (s; None
        before sync, or before the start); None: the runtime's own heading guidance.
        ``own``: this platform's estimate (common frame if framed); ``frozen``: the run
        is paused (the reference stands still)."""

    def new_run(self) -> None:
        """A run was armed: what one run's guidance keeps begins afresh (nothing here)."""
        return None

    @property
    def counters(self) -> dict[Count, int]:
        """Counters for the agent's status and recordings (none here)."""
        return {}

    def fields(self) -> dict[str, float | str | None]:
        """Values recorded with each reference beyond the position reference (none here)."""
        return {}

"""A platform kind defined outside the fedlab package: ``still:X,Y``, a platform that
stays at one point of its table whatever it is told (a mock-up in place of a table).

All a new kind takes: this module (a class with the :class:`~agents.interface.Platform`
capabilities, here :class:`~agents.interface.WithoutChain`'s, and its ``kind``,
``check_spec`` and ``from_spec``) and one registration: ``register_platform(StillPlatform)``
in code, or a ``fedlab.platforms`` entry point ``still = "still_platform:StillPlatform"``.
"""

from __future__ import annotations

from agents.guidance import Track
from agents.interface import WithoutChain
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

__all__ = ["StillPlatform"]


class StillPlatform(WithoutChain):
    """At (x, y) m, heading 0, for good."""

    kind = "still"
    argument = "X,Y"
    hardware = False
    config: PlatformConfig | None = None

    @staticmethod
    def _point(argument: str | None) -> tuple[float, float]:
        try:
            x, y = (float(v) for v in (argument or "").split(","))
        except ValueError:
            raise ValueError(f"still:X,Y takes two numbers (m), not {argument!r}") from None
        return x, y

    @classmethod
    def check_spec(cls, argument: str | None) -> None:
        cls._point(argument)

    @classmethod
    def from_spec(
        cls, argument: str | None, *, seed: int, rate: float, preset: str | None
    ) -> StillPlatform:
        return cls(*cls._point(argument), rate=rate)

    def __init__(self, x: float, y: float, rate: float = 20.0):
        self.rate = rate
        self.pose = Pose(x, y)
        self.held = False

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        return self.pose

    def hold(self) -> None:
        self.held = True

    def release(self) -> None:
        self.held = False

    def close(self) -> None:
        self.held = True

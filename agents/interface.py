"""What the agent runtime drives: the :class:`Platform` protocol and :class:`PlatformError`.

The protocol states every capability the runtime, the scenarios and the recordings
read of a platform, with its type: a new kind of platform implements these and
nothing else is asked of it. Two mixins give them: :class:`WithoutChain` the values of
a platform that has no GNC chain (its pose is the command, or a measurement taken as
it comes: always a fix, no valves, nothing restarted, nothing rejected), and
:class:`WithChain` those of a platform flown by a :class:`~agents.gnc.GncChain`
(simulated, serial), read from its chain.

Rule: this module imports no platform, so every platform module (kinematic,
simulated, serial) and :mod:`agents.platform`, which builds them, can import it
without an import cycle. Import both names from :mod:`agents.platform`.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Literal, Protocol, get_args, runtime_checkable

from agents.control import HeadingPid
from agents.guidance import Track
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig

if TYPE_CHECKING:
    from agents.gnc import GncChain

__all__ = [
    "CLOSED_CAUSES",
    "ClosedCause",
    "Platform",
    "PlatformError",
    "WithChain",
    "WithoutChain",
]

ClosedCause = Literal[
    "no_fix",
    "device_restart",
    "fix_restart",
    "fix_rejected",
    "stale_fix",
    "stale_imu",
    "settling",
    "nonfinite",
]
"""Why a platform's GNC chain keeps every valve closed, apart from a hold
(:mod:`agents.gnc`, "Fails closed"):

- ``no_fix``: no metrology fix yet (the estimate is the filter's prior);
- ``device_restart``: the device's clock went back, its restart not yet confirmed;
- ``fix_restart``: the estimate restarted from agreeing outlier fixes, not yet
  acknowledged (:meth:`Platform.acknowledge_restart`);
- ``fix_rejected``: the latest fix was rejected (:attr:`Platform.last_rejection`);
- ``stale_fix``: the latest fix is older than the preset's ``control.fix_timeout``;
- ``stale_imu``: no IMU sample for ``control.imu_timeout``;
- ``settling``: an estimate just acquired, its velocity not yet known well enough;
- ``nonfinite``: a reference, the estimate or a demand is not a finite number."""

CLOSED_CAUSES: tuple[ClosedCause, ...] = get_args(ClosedCause)
"""Every :data:`ClosedCause`, in the chain's order of precedence."""


class PlatformError(RuntimeError):
    """The platform cannot be driven (a serial port vanished, say); valves are closed."""


@runtime_checkable
class Platform(Protocol):
    """A pose source driven by a heading command (and optionally a position track).

    The agent calls :meth:`step` :attr:`rate` times a second with its clock's time
    and the guidance's heading and rate references; the returned pose is what it
    publishes (for a simulated or real platform: its navigation estimate).
    :meth:`hold` closes every valve until :meth:`release` (safe hold); :meth:`close`
    closes them for good and releases what the platform holds (a serial port).

    The properties below :meth:`close` are what the agent reads every step, in
    preflight and in its status and recordings; a platform without a GNC chain gives
    :class:`WithoutChain`'s values.
    """

    @property
    def rate(self) -> float:
        """Steps per second the platform expects, Hz."""
        ...

    @property
    def config(self) -> PlatformConfig | None:
        """The physical description (mass, inertia, gains); None for a kinematic one."""
        ...

    @property
    def held(self) -> bool:
        """Whether :meth:`hold` is in force."""
        ...

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """Advance to ``t`` (s) towards ``heading_ref`` (rad) at ``rate_ref`` (rad/s) and,
        if given, along ``track`` (a position reference with its rates, 3-DOF)."""
        ...

    def hold(self) -> None:
        """Close every valve now and keep them closed until :meth:`release`."""
        ...

    def release(self) -> None:
        """End :meth:`hold`: control resumes from a clean start."""
        ...

    def close(self) -> None:
        """Every valve closed, resources released; idempotent."""
        ...

    # -- what the agent reads ----------------------------------------------------------
    @property
    def has_fix(self) -> bool:
        """Whether the pose :meth:`step` returns rests on a measurement: a GNC chain's
        estimate once a metrology fix has been taken (before, it is the filter's prior:
        not a pose to publish or steer by); always True for a platform whose pose is
        the command or a measurement itself."""
        ...

    @property
    def restarted(self) -> bool:
        """The estimate restarted from agreeing outlier fixes and no operator has
        acknowledged it yet (:meth:`acknowledge_restart`): the valves stay closed
        (``fix_restart``). Always False for a platform without a GNC chain."""
        ...

    def acknowledge_restart(self) -> None:
        """An operator has seen :attr:`restarted` (``fedlab ctl reset``): control may
        resume on the restarted estimate. Nothing to do without a GNC chain."""
        ...

    @property
    def cause(self) -> ClosedCause | None:
        """Why every valve would be closed now were the platform not held (None: they
        may open), as preflight tells an operator of a platform waiting for its run."""
        ...

    @property
    def acquiring(self) -> tuple[int, int] | None:
        """While metrology fixes are being acquired (a first fix, or fixes after a gap):
        how many agree so far and how many it takes; None otherwise."""
        ...

    @property
    def last_rejection(self) -> str | None:
        """Why the latest measurement was refused (``fix_outside``, ``fix_late``,
        ``fix_outlier``, ... for a GNC chain's fixes); None before any."""
        ...

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight valve states now (:data:`agents.dynamics.THRUSTERS`' order), open
        True; empty for a platform with no valves (kinematic, a ROS 2 platform)."""
        ...

    @property
    def valves_confirmed(self) -> bool | None:
        """Whether the device took the last valve command whole (False: a write was cut
        off, :attr:`valves` is what was commanded, all closed); None: no device to
        confirm it (simulated, kinematic)."""
        ...

    @property
    def truth(self) -> Pose | None:
        """A simulated platform's true pose, in the frame :meth:`step` returns poses in
        (for evaluation only, never published as the pose); None for any other."""
        ...

    @property
    def counters(self) -> Mapping[Count, int]:
        """The platform's own counters (steps closed per cause, fixes rejected, a serial
        link's bad frames, ...), merged into the agent's status and recordings."""
        ...

    @property
    def heading_pid(self) -> HeadingPid | None:
        """The heading controller whose gains adaptive gains schedule
        (:class:`~agents.adaptive.AdaptiveGains`); None: the platform has none."""
        ...


class WithoutChain:
    """The capabilities of a platform with no GNC chain: its pose is always a fix, it
    has no valves, nothing restarts and nothing is rejected.

    :attr:`last_rejection` and :attr:`counters` are class attributes, so a subclass may
    keep its own as instance attributes (an odometry platform keeps its counters and its
    last refused sample); the others are properties a subclass may override.
    """

    last_rejection: str | None = None
    counters: Mapping[Count, int] = MappingProxyType({})

    @property
    def has_fix(self) -> bool:
        return True

    @property
    def restarted(self) -> bool:
        return False

    def acknowledge_restart(self) -> None:
        """Nothing restarts: nothing to acknowledge."""

    @property
    def cause(self) -> ClosedCause | None:
        return None

    @property
    def acquiring(self) -> tuple[int, int] | None:
        return None

    @property
    def valves(self) -> tuple[bool, ...]:
        return ()

    @property
    def valves_confirmed(self) -> bool | None:
        return None

    @property
    def truth(self) -> Pose | None:
        return None

    @property
    def heading_pid(self) -> HeadingPid | None:
        return None


class WithChain:
    """The capabilities of a platform flown by a GNC chain, read from :attr:`chain`
    (the platform gives its own :attr:`Platform.valves`, :attr:`Platform.truth`,
    :attr:`Platform.valves_confirmed` and :attr:`Platform.counters`)."""

    chain: GncChain

    @property
    def has_fix(self) -> bool:
        return self.chain.fix_time is not None

    @property
    def restarted(self) -> bool:
        return self.chain.restarted

    def acknowledge_restart(self) -> None:
        self.chain.acknowledge_restart()

    @property
    def cause(self) -> ClosedCause | None:
        cause = self.chain.cause
        # The chain's cause is never "held" (that is its reason's, while held).
        return None if cause is None or cause == "held" else cause

    @property
    def acquiring(self) -> tuple[int, int] | None:
        return self.chain.acquiring

    @property
    def last_rejection(self) -> str | None:
        return self.chain.last_rejection

    @property
    def heading_pid(self) -> HeadingPid:
        return self.chain.pid

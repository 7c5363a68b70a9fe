"""The Platform protocol (agents/interface.py): every kind of platform states every
capability the agent reads, with the values its kind has."""

from __future__ import annotations

import math
import os
import tty
from collections.abc import Iterator
from typing import Any

import pytest

from agents.gnc import CLOSED
from agents.interface import CLOSED_CAUSES, Platform, WithChain
from agents.kinematic import KinematicPlatform
from agents.serial.platform import SerialPlatform
from agents.simulated import SimulatedPlatform
from agents.workspace import Frame, FramedPlatform
from federation.core.wire import Pose
from schemas.platform import load_platform

KNATTE = load_platform("knatte")
CAPABILITIES = (
    "has_fix", "restarted", "cause", "acquiring", "last_rejection", "valves",
    "valves_confirmed", "truth", "counters", "heading_pid",
)  # fmt: skip


@pytest.fixture
def pty_path() -> Iterator[str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def _odometry() -> Any:
    from federation.bridge.ros2 import OdometryPlatform

    class _Reader:
        def take(self, N: int) -> list[Any]:
            return []

    platform = OdometryPlatform(_Reader(), timeout=0.5)  # type: ignore[arg-type]
    platform.received_at = 0.0  # as if a valid odometry sample had been taken
    return platform


def _sdk_source() -> Platform:
    from federation.runtime.sdk import _SourcePlatform

    return _SourcePlatform(lambda t: Pose(1.0, 2.0), 20.0, lambda t: t)


def _without_chain(platform: Platform) -> None:
    """A platform with no GNC chain: always a fix, no valves, nothing to restart."""
    assert platform.has_fix is True
    assert platform.restarted is False
    assert platform.cause is None and platform.acquiring is None
    assert platform.last_rejection is None
    assert platform.valves == () and platform.valves_confirmed is None
    assert platform.truth is None and platform.heading_pid is None
    assert dict(platform.counters) == {}
    platform.acknowledge_restart()  # nothing to acknowledge, and no error


@pytest.mark.parametrize(
    "build",
    [
        KinematicPlatform,
        _odometry,
        _sdk_source,
        lambda: FramedPlatform(KinematicPlatform(), Frame((1.0, 0.0))),
    ],
    ids=["kinematic", "ros2-odometry", "sdk-source", "framed-kinematic"],
)
def test_a_platform_without_a_chain_states_its_capabilities(build: Any) -> None:
    platform = build()
    assert isinstance(platform, Platform)
    if isinstance(platform, FramedPlatform):
        assert platform.chain is None
        assert platform.counters == {"workspace_clamped": 0, "workspace_holds": 0}
        platform.workspace_counters.clear()
    _without_chain(platform)


def test_a_ros2_platform_has_no_fix_before_its_first_odometry() -> None:
    platform = _odometry()
    platform.received_at = None
    assert isinstance(platform, Platform) and platform.has_fix is False


def test_a_simulated_platform_reports_its_chain_before_and_after_its_first_fix() -> None:
    platform = SimulatedPlatform(KNATTE, seed=1, disturbance=False)
    assert isinstance(platform, Platform)
    platform.step(0.0, 0.0, 0.0)
    assert platform.has_fix is False and platform.cause == "no_fix"
    assert platform.acquiring == (1, 3) and platform.restarted is False  # its first fix
    assert platform.valves == CLOSED and platform.valves_confirmed is None
    assert platform.truth == platform.plant.pose
    assert platform.heading_pid is platform.chain.pid
    assert platform.counters["closed_no_fix"] == 1
    t = 0.0
    while platform.cause is not None and t < 10.0:  # fixes acquired, then settled
        t += 0.01
        platform.step(t, 0.0, 0.0)
    assert platform.has_fix is True and platform.cause is None
    assert platform.last_rejection is None


def test_a_serial_platform_reports_its_chain_and_its_device(pty_path: str) -> None:
    with SerialPlatform(pty_path, KNATTE) as platform:
        assert isinstance(platform, Platform)
        assert platform.has_fix is False and platform.cause == "no_fix"
        assert platform.valves == CLOSED and platform.valves_confirmed is True
        assert platform.truth is None  # a real platform's truth is not known
        assert platform.heading_pid is platform.chain.pid
        assert "frames_ok" in platform.counters and "closed_no_fix" in platform.counters


def test_a_framed_platform_forwards_every_capability_in_the_common_frame() -> None:
    inner = SimulatedPlatform(KNATTE, seed=1, disturbance=False, x=0.2, y=0.1)
    framed = FramedPlatform(inner, Frame((1.0, -2.0), math.pi / 2))
    assert isinstance(framed, Platform)
    framed.step(0.0, 0.0, 0.0)
    for name in CAPABILITIES:
        if name not in ("truth", "counters"):
            assert getattr(framed, name) == getattr(inner, name), name
    assert framed.chain is inner.chain
    assert framed.truth is not None
    assert (framed.truth.x, framed.truth.y) == pytest.approx((0.9, -1.8))  # common frame
    assert framed.counters == inner.counters | framed.workspace_counters


class _Chain:
    """What :class:`WithChain` reads of a chain, set by hand."""

    fix_time = 3.0
    restarted = True
    cause = "fix_restart"
    acquiring = (2, 3)
    last_rejection = "fix_outlier"
    pid = object()

    def acknowledge_restart(self) -> None:
        self.restarted = False
        self.cause = "held"  # the chain's reason while held, never a cause


def test_a_platform_with_a_chain_reads_each_capability_from_it() -> None:
    platform = WithChain()
    platform.chain = _Chain()  # type: ignore[assignment]
    assert platform.has_fix is True and platform.restarted is True
    assert platform.cause == "fix_restart" and platform.cause in CLOSED_CAUSES
    assert platform.acquiring == (2, 3) and platform.last_rejection == "fix_outlier"
    assert platform.heading_pid is _Chain.pid
    platform.acknowledge_restart()
    assert platform.restarted is False
    assert platform.cause is None  # "held" is a hold, not a cause

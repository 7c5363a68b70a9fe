"""What the ROS 2 bridge refuses, both ways: a federation member's bad status or pose
skips that member only (it had stopped the bridge), and a joined platform's odometry is
taken only if it is fresh, newer, in the frames first taken and from one publisher."""

from __future__ import annotations

import json
import math
import time
from types import SimpleNamespace
from typing import Any

import pytest

from federation.bridge import ros2_core as conv
from federation.bridge.ros2 import FederationToRos, OdometryPlatform
from federation.bridge.ros2_types import Odometry, odometry_message
from federation.core import wire
from federation.core.keys import AgentId
from federation.runtime.foxglove import run_row
from schemas.messages import Status

GOOD, BAD = "kiruna/knatte", "evil/x"
ROVER = AgentId.parse("ros2lab/rover")


class _Payload:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, key: str, data: bytes):
        self.key_expr, self.payload = key, _Payload(data)


class _Writer:
    def __init__(self) -> None:
        self.written = 0

    def write(self, message: Any) -> None:
        message.serialize()  # what a DataWriter does first: fails on a value it cannot hold
        self.written += 1


def _status(agent: str, t_exec: float, t_sim: float) -> bytes:
    return json.dumps({
        "agent": agent, "federation": "default", "role": "member", "reference": GOOD,
        "t_exec": t_exec, "host_monotonic": 0.0, "t_sim": t_sim, "pose": [0] * 6, "peers": {},
    }).encode()  # fmt: skip


@pytest.mark.parametrize(
    ("t_exec", "t_sim", "t"),
    [(0.0, math.nan, 1.0), (-1e308, 1e308, 1.0), (0.0, 0.0, 1e12), (0.0, 0.0, 1e300)],
    ids=["status t_sim NaN", "offset overflowing", "pose beyond ROS time", "pose overflowing"],
)
def test_one_members_bad_status_or_pose_skips_that_member_only(
    t_exec: float, t_sim: float, t: float
) -> None:
    bridge = FederationToRos(session=None, participant=None)  # type: ignore[arg-type]
    bridge.reference_offset = lambda now: 0.0  # type: ignore[method-assign]
    writers = {AgentId.parse(a): _Writer() for a in (BAD, GOOD)}
    bridge._writers = writers  # type: ignore[assignment]
    bridge._tf = _Writer()  # type: ignore[assignment]
    bridge._on_status(_Sample(f"fedlab/default/{BAD}/status", _status(BAD, t_exec, t_sim)))
    bridge._on_status(_Sample(f"fedlab/default/{GOOD}/status", _status(GOOD, 5.0, 5.0)))
    bridge._on_pose(_Sample(f"fedlab/default/{BAD}/pose", wire.encode_pose(t, wire.Pose())))
    bridge._on_pose(_Sample(f"fedlab/default/{GOOD}/pose", wire.encode_pose(5.0, wire.Pose())))
    assert bridge.publish() == 1  # no exception: the good member's odometry written
    assert writers[AgentId.parse(GOOD)].written == 1 and writers[AgentId.parse(BAD)].written == 0
    refused = bridge.counters["status_malformed"] + bridge.counters["odom_unwritable"]
    assert refused == 1, bridge.counters


def test_a_velocity_too_large_to_turn_is_refused_both_ways() -> None:
    # Finite in one frame, infinite once turned: toward the federation it held the
    # platform for good (nonfinite) on one sample; toward ROS an infinite twist went out.
    q = (0.0, 0.0, math.sin(math.pi / 8), math.cos(math.pi / 8))
    with pytest.raises(conv.OdometryError, match="not finite in the common frame"):
        conv.pose_from_odometry((0, 0, 0), q, (1.7e308, 1.7e308, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="not finite in the body frame"):
        conv.odometry_fields(ROVER, wire.Pose(0, 0, 0.785, 1.7e308, 1.7e308, 0), 1.0)
    with pytest.raises(ValueError, match="beyond what ROS 2 time holds"):
        conv.split_stamp(2.0**31)
    assert conv.split_stamp(2.0**31 - 1) == (2**31 - 1, 0)


def test_a_non_finite_time_in_a_status_leaves_the_live_run_table_json() -> None:
    status = Status.model_validate_json(_status(BAD, 0.0, math.nan))
    row = run_row(status)
    assert row["t_sim"] is None
    json.dumps(row, allow_nan=False)  # Foxglove's parser takes no NaN: the table had gone


class _Reader:
    def __init__(self) -> None:
        self.samples: list[Odometry] = []

    def take(self, N: int) -> list[Odometry]:
        taken, self.samples = self.samples, []
        return taken


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _odometry(
    stamp: float, x: float = 1.0, frame: str = "odom", child: str = "base_link", writer: int = 1
) -> Odometry:
    message = odometry_message(conv.odometry_fields(ROVER, wire.Pose(x, 2.0, 0.3), stamp))
    message.header.frame_id, message.child_frame_id = frame, child
    message.sample_info = SimpleNamespace(publication_handle=writer)  # as DDS annotates it
    return message


def _platform() -> tuple[OdometryPlatform, _Reader, _Clock, _Clock]:
    reader, clock, wall = _Reader(), _Clock(), _Clock()
    wall.now = time.time()
    platform = OdometryPlatform(reader, timeout=0.5, clock=clock, wall=wall)  # type: ignore[arg-type]
    return platform, reader, clock, wall


def test_odometry_is_taken_fresh_newer_in_its_frames_and_from_one_publisher() -> None:
    platform, reader, clock, wall = _platform()
    reader.samples = [_odometry(wall.now)]
    platform.step(0, 0, 0)
    assert not platform.stale and platform.pose.x == 1.0
    assert platform.frames == ("odom", "base_link")

    refused = {
        "odom_clock": _odometry(wall.now - 3600, x=9.0),  # an hour-old bag replayed
        "odom_foreign_frame": _odometry(wall.now + 0.1, x=9.0, frame="map"),
        "odom_not_newer": _odometry(wall.now - 0.5, x=9.0),  # older than the one taken
    }
    for kind, sample in refused.items():
        reader.samples = [sample]
        platform.step(0, 0, 0)
        assert platform.counters[kind] == 1, (kind, platform.counters)
        assert platform.pose.x == 1.0, kind
    reader.samples = [_odometry(wall.now + 0.1, x=9.0, child="other_robot")]
    platform.step(0, 0, 0)
    assert platform.counters["odom_foreign_frame"] == 2 and platform.pose.x == 1.0

    # A stuck node sending its last sample again refreshes nothing: stale in time.
    for _ in range(6):
        clock.now += 0.1
        reader.samples = [_odometry(wall.now, x=9.0)]
        platform.step(0, 0, 0)
    assert platform.stale and platform.counters["odom_not_newer"] == 7
    assert platform.last_rejection is not None and "after the last" in platform.last_rejection

    # A second writer on the topic: nothing taken from either while both are heard.
    reader.samples = [_odometry(wall.now + 0.2, x=9.0, writer=2), _odometry(wall.now + 0.3)]
    platform.step(0, 0, 0)
    assert platform.counters["odom_contested"] == 2 and platform.stale and platform.pose.x == 1.0
    # The first falls silent (a node killed and started again is a new writer): after
    # the timeout the one heard is taken again, without waiting for a DDS lease.
    clock.now += 0.6
    reader.samples = [_odometry(wall.now + 0.4, x=3.0, writer=2)]
    platform.step(0, 0, 0)
    assert not platform.stale and platform.pose.x == 3.0


def test_clocks_set_back_hold_the_platform_no_longer_than_the_tolerance() -> None:
    # The last stamp taken had been kept for good: clocks corrected back by 60 s (NTP)
    # made every fresh sample "not newer" for 60 s, the platform held all that time.
    platform, reader, clock, wall = _platform()
    reader.samples = [_odometry(wall.now)]
    platform.step(0, 0, 0)
    wall.now -= 60.0
    for _ in range(30):  # 3 s at 10 Hz on the corrected clocks
        clock.now += 0.1
        wall.now += 0.1
        reader.samples = [_odometry(wall.now, x=2.0)]
        platform.step(0, 0, 0)
    assert not platform.stale and platform.pose.x == 2.0

"""The ROS 2 bridge's conversions (federation/bridge/ros2_core.py): names, frames, stamps."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.bridge import ros2_core as conv
from federation.bridge.ros2_types import odometry_message, tf_message
from federation.core.keys import AgentId
from federation.core.wire import Pose

KNATTE = AgentId("kiruna", "knatte")
finite = st.floats(-1e3, 1e3, allow_nan=False)


def test_names_follow_ros2_conventions() -> None:
    assert conv.odometry_topic(KNATTE) == "/fedlab/kiruna/knatte/odom"
    assert conv.dds_topic(conv.odometry_topic(KNATTE)) == "rt/fedlab/kiruna/knatte/odom"
    assert conv.dds_topic("/tf") == "rt/tf"
    assert conv.dds_topic("odom") == "rt/odom"  # relative names resolve in the root namespace
    assert conv.dds_type_name("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
    assert conv.agent_frame(KNATTE) == "kiruna/knatte"


@pytest.mark.parametrize("bad", ["", "/", "/a//b", "/a/", "/1odom", "/odom-raw", "/a b"])
def test_invalid_topic_names_are_refused_saying_why(bad: str) -> None:
    with pytest.raises(ValueError, match="invalid ROS 2 topic"):
        conv.ros_topic(bad)


def test_stamps_split_into_whole_seconds_and_nanoseconds() -> None:
    assert conv.split_stamp(1.5) == (1, 500_000_000)
    assert conv.split_stamp(-0.25) == (-1, 750_000_000)  # nanosec stays in [0, 1e9)
    assert conv.split_stamp(2.9999999999) == (3, 0)  # rounds to the nearest ns, carrying
    assert conv.stamp_seconds(*conv.split_stamp(1_700_000_000.123456789)) == pytest.approx(
        1_700_000_000.123456789, abs=1e-6
    )
    with pytest.raises(ValueError, match="finite"):
        conv.split_stamp(math.nan)


def test_host_stamp_maps_the_senders_clock_through_reference_time() -> None:
    # Sender 26.42 s behind the reference; the reference 100 s ahead of the bridge's
    # monotonic clock; the bridge's wall clock 1.7e9 s ahead of its monotonic clock.
    mono, wall = 50.0, 1.7e9 + 50.0
    t = 120.0 - 26.42  # the sender's clock at reference time 120, i.e. bridge monotonic 20
    stamp = conv.host_stamp(t, 26.42, 100.0, mono, wall)
    assert stamp == pytest.approx(1.7e9 + 20.0, abs=1e-6)


@given(finite, finite, st.floats(-math.pi, math.pi), finite, finite, finite)
def test_pose_survives_odometry_and_back(
    x: float, y: float, heading: float, vx: float, vy: float, omega: float
) -> None:
    pose = Pose(x, y, heading, vx, vy, omega)
    f = conv.odometry_fields(KNATTE, pose, 10.0)
    back = conv.pose_from_odometry(f.position, f.orientation, f.linear, f.angular)
    assert back.x == x and back.y == y and back.omega == omega
    assert math.remainder(back.heading - heading, math.tau) == pytest.approx(0.0, abs=1e-12)
    assert back.vx == pytest.approx(vx, abs=1e-9) and back.vy == pytest.approx(vy, abs=1e-9)


def test_odometry_fields_put_the_twist_in_the_child_frame() -> None:
    # Heading 90 degrees, moving along common +y: forward (+x) in the body frame.
    f = conv.odometry_fields(KNATTE, Pose(1.0, 2.0, math.pi / 2, 0.0, 0.5, 0.1), 3.25)
    assert f.frame_id == "fedlab_common" and f.child_frame_id == "kiruna/knatte"
    assert f.stamp == (3, 250_000_000)
    assert f.position == (1.0, 2.0, 0.0)
    assert f.orientation == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert f.linear == pytest.approx((0.5, 0.0, 0.0), abs=1e-15)
    assert f.angular == (0.0, 0.0, 0.1)
    t = conv.transform_fields(KNATTE, Pose(1.0, 2.0, math.pi / 2), 3.25)
    assert (t.frame_id, t.child_frame_id, t.translation) == (
        "fedlab_common", "kiruna/knatte", (1.0, 2.0, 0.0),
    )  # fmt: skip
    assert t.rotation == f.orientation


@pytest.mark.parametrize(
    ("orientation", "linear", "why"),
    [
        ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "not a unit quaternion"),
        ((0.0, 0.0, 0.0, 2.0), (0.0, 0.0, 0.0), "not a unit quaternion"),
        ((0.0, 0.0, math.nan, 1.0), (0.0, 0.0, 0.0), "not finite"),
        ((math.sin(0.25), 0.0, 0.0, math.cos(0.25)), (0.0, 0.0, 0.0), "not level"),
        ((0.0, 0.0, 0.0, 1.0), (math.inf, 0.0, 0.0), "linear .* not finite"),
    ],
)
def test_unusable_odometry_is_refused_saying_why(
    orientation: tuple[float, float, float, float], linear: tuple[float, float, float], why: str
) -> None:
    with pytest.raises(conv.OdometryError, match=why):
        conv.pose_from_odometry((0.0, 0.0, 0.0), orientation, linear, (0.0, 0.0, 0.0))


def test_a_slightly_unnormalized_quaternion_is_normalized() -> None:
    q = conv.heading_quaternion(0.7)
    scaled = tuple(1.0005 * v for v in q)
    pose = conv.pose_from_odometry((0.0, 0.0, 0.0), scaled, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    assert pose.heading == pytest.approx(0.7, abs=1e-12)


def test_dds_messages_carry_the_fields_and_serialize_as_xcdr1() -> None:
    f = conv.odometry_fields(KNATTE, Pose(1.0, -2.0, 0.3, 0.1, 0.2, 0.05), 12.5)
    message = odometry_message(f)
    assert message.header.stamp.sec == 12 and message.header.stamp.nanosec == 500_000_000
    assert message.child_frame_id == "kiruna/knatte"
    assert message.pose.pose.position.x == 1.0 and len(message.pose.covariance) == 36
    data = message.serialize()
    assert data[:2] == b"\x00\x01"  # CDR little-endian (XCDR1), what ROS 2 exchanges
    assert type(message).deserialize(data) == message
    tf = tf_message([conv.transform_fields(KNATTE, Pose(1.0, -2.0, 0.3), 12.5)])
    assert type(tf).__idl__.idl_transformed_typename == "tf2_msgs::msg::dds_::TFMessage_"
    assert type(tf).deserialize(tf.serialize()) == tf


@pytest.mark.parametrize(
    ("mode", "reason", "hold"),
    [
        ("running", None, False),
        ("running", "stale", True),  # the link or the odometry
        ("running", "contested", True),
        ("waiting", None, True),
        ("armed", None, True),
        ("frozen", None, True),
        ("aborted", "aborted", True),
        ("done", "done", True),
    ],
)
def test_a_joined_platform_may_move_only_in_a_running_run_not_held(
    mode: str, reason: str | None, hold: bool
) -> None:
    assert conv.must_hold(mode, reason) is hold


def test_state_is_written_on_a_change_and_again_every_period() -> None:
    news = conv.Repeated(every=1.0)
    assert news.due(True, 0.0)  # the first
    assert not news.due(True, 0.5)
    assert news.due(False, 0.6)  # a change: at once
    assert not news.due(False, 1.5)
    assert news.due(False, 1.6)  # unchanged for a period: again
    assert news.due(True, 1.61)
    with pytest.raises(ValueError, match="positive"):
        conv.Repeated(every=0.0)


def test_an_agents_topics_are_under_its_name() -> None:
    rover = AgentId("ros2lab", "rover")
    assert conv.agent_topic(rover, "hold") == "/fedlab/ros2lab/rover/hold"
    assert conv.odometry_topic(rover) == "/fedlab/ros2lab/rover/odom"


class _Writer:
    def __init__(self) -> None:
        self.written: list[object] = []

    def write(self, sample: object) -> None:
        self.written.append(sample)


def test_after_close_the_hold_is_the_last_word_to_ros() -> None:
    """A step of the agent's loop still under way as the bridge stops wrote hold = false
    after the closing hold = true."""
    import threading
    from collections import Counter

    from federation.bridge.ros2 import RunStateToRos
    from federation.bridge.ros2_types import Bool

    state = object.__new__(RunStateToRos)  # its DDS writers replaced by lists
    state.clock = lambda: 0.0
    state._hold, state._run = _Writer(), _Writer()  # type: ignore[assignment]
    state._hold_news, state._run_news = conv.Repeated(), conv.Repeated()
    state.counters, state._lock, state._closed = Counter(), threading.Lock(), False
    state.publish("running", None)
    state.close()
    state.publish("running", None)  # the loop's last step, after close
    assert state._hold.written == [Bool(False), Bool(True)]  # type: ignore[attr-defined]

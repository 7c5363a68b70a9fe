"""The ROS 2 message types the bridge speaks, as Cyclone DDS types named as ROS 2 maps them.

Each class is the DDS struct ROS 2 generates from the ``.msg`` (``rosidl``'s IDL, module
``pkg::msg::dds_``, type ``Name_``), field for field and in order, so a ROS 2 node on
Cyclone DDS (``rmw_cyclonedds_cpp``) or any RTPS middleware reads and writes them:

==================================  ========================================================
``builtin_interfaces/msg/Time``     int32 sec, uint32 nanosec
``std_msgs/msg/Header``             Time stamp, string frame_id
``geometry_msgs/msg/Point``         float64 x, y, z (also ``Vector3``)
``geometry_msgs/msg/Quaternion``    float64 x, y, z, w
``geometry_msgs/msg/Pose``          Point position, Quaternion orientation
``geometry_msgs/msg/Twist``         Vector3 linear, angular
``...WithCovariance``               the above, float64[36] covariance (row-major 6x6)
``nav_msgs/msg/Odometry``           Header header, string child_frame_id,
                                    PoseWithCovariance pose, TwistWithCovariance twist
``geometry_msgs/msg/Transform``     Vector3 translation, Quaternion rotation
``.../TransformStamped``            Header header, string child_frame_id, Transform transform
``tf2_msgs/msg/TFMessage``          sequence<TransformStamped> transforms
``std_msgs/msg/Bool``               boolean data
``std_msgs/msg/String``             string data
==================================  ========================================================

No I/O here: :mod:`federation.bridge.ros2` makes topics, readers and writers of them.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t

from federation.bridge.ros2_core import OdometryFields, TransformFields

__all__ = [
    "Bool",
    "Header",
    "Odometry",
    "Point",
    "Pose",
    "PoseWithCovariance",
    "Quaternion",
    "String",
    "TFMessage",
    "Time",
    "Transform",
    "TransformStamped",
    "Twist",
    "TwistWithCovariance",
    "Vector3",
    "odometry_message",
    "tf_message",
]

# ROS 2's DDS names are pkg::msg::dds_::Type_; cyclonedds writes "." as "::". No
# `from __future__ import annotations` here: cyclonedds resolves the annotations itself.


@dataclass
class Time(IdlStruct, typename="builtin_interfaces.msg.dds_.Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs.msg.dds_.Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Point(IdlStruct, typename="geometry_msgs.msg.dds_.Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs.msg.dds_.Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs.msg.dds_.Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs.msg.dds_.Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


# t.array[t.float64, 36] spelled out, so that mypy reads it without cyclonedds' plugin.
Covariance = Annotated[Sequence[float], t.array(t.float64, 36)]
"""float64[36]: a row-major 6x6 covariance."""


def _zeros() -> list[float]:
    return [0.0] * 36


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs.msg.dds_.PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: Covariance = field(default_factory=_zeros)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs.msg.dds_.Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs.msg.dds_.TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: Covariance = field(default_factory=_zeros)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs.msg.dds_.Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs.msg.dds_.Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs.msg.dds_.TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


Transforms = Annotated[Sequence[TransformStamped], t.sequence(TransformStamped)]


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs.msg.dds_.TFMessage_"):
    transforms: Transforms = field(default_factory=list)


@dataclass
class Bool(IdlStruct, typename="std_msgs.msg.dds_.Bool_"):
    data: bool = False


@dataclass
class String(IdlStruct, typename="std_msgs.msg.dds_.String_"):
    data: str = ""


def odometry_message(f: OdometryFields) -> Odometry:
    """An :class:`Odometry` sample of ``f``."""
    return Odometry(
        header=Header(Time(*f.stamp), f.frame_id),
        child_frame_id=f.child_frame_id,
        pose=PoseWithCovariance(Pose(Point(*f.position), Quaternion(*f.orientation))),
        twist=TwistWithCovariance(Twist(Vector3(*f.linear), Vector3(*f.angular))),
    )


def tf_message(transforms: list[TransformFields]) -> TFMessage:
    """A :class:`TFMessage` of ``transforms``."""
    return TFMessage(
        [
            TransformStamped(
                Header(Time(*f.stamp), f.frame_id),
                f.child_frame_id,
                Transform(Vector3(*f.translation), Quaternion(*f.rotation)),
            )
            for f in transforms
        ]
    )

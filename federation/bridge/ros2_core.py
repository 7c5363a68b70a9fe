r"""The ROS 2 bridge's conversions, free of I/O: a fedlab pose and its time in,
``nav_msgs/msg/Odometry`` and ``geometry_msgs/msg/TransformStamped`` fields out, and back.

Nothing here imports DDS, reads a clock or touches a session: :mod:`federation.bridge.ros2`
moves the samples and passes ``now`` in, so a test can check every field exactly.

Rules this module keeps
-----------------------
Names (ROS 2's conventions)
    Every federation agent ``LAB/NAME`` is published on ``/fedlab/LAB/NAME/odom`` (DDS topic
    ``rt/fedlab/LAB/NAME/odom``) and as the TF frame ``LAB/NAME``, child of
    ``fedlab_common``, the federation's common frame. DDS type names are ROS 2's mapping of
    ``pkg/msg/Type``: ``pkg::msg::dds_::Type_``. A ROS topic name is absolute or relative
    (``odom`` is ``/odom``), of letters, digits, ``_`` and ``/``; no token starts with a
    digit, no ``//``, no trailing ``/``.
Frames and units
    Position ``(x, y, 0)`` m in ``fedlab_common``; orientation the rotation by ``heading``
    about z:

    .. math:: q = (0,\ 0,\ \sin(\psi/2),\ \cos(\psi/2)).

    ROS puts the twist in the *child* frame (REP 105, ``nav_msgs/Odometry``): the body
    velocity is the common-frame velocity rotated by :math:`-\psi`,

    .. math:: v_b = R(-\psi)\,(v_x, v_y)^T, \qquad \omega_b = \omega.

    Back from ROS: the heading is the yaw of the quaternion (which must be unit within
    ``QUATERNION_TOLERANCE`` and level: roll and pitch below ``LEVEL_TOLERANCE``, as
    air-bearing platforms are), the velocity rotated by :math:`+\psi`. Anything
    non-finite is refused with :class:`OdometryError` (a ``ValueError``) saying what.
Time
    ROS stamps are the bridge host's clock (``builtin_interfaces/Time``: seconds since
    the epoch, whole ``sec`` and ``nanosec`` in [0, 1e9)). A pose stamped ``t`` on its
    sender's clock is on reference time ``t + r`` (``r``: the sender's own estimate of
    the reference clock minus its clock, from its status) and on the bridge host's wall
    clock

    .. math:: w = w_{now} + (t + r - \theta - m_{now}),

    where :math:`\theta` is the reference clock minus the bridge's monotonic clock
    (the bridge's own sync with the reference), :math:`m_{now}` and :math:`w_{now}` the
    bridge's monotonic and wall clocks read together.
A joined platform's run state (what ROS must obey)
    A ROS 2 platform's actuators are commanded in ROS, so the bridge tells ROS what the
    federation decided: ``/fedlab/LAB/NAME/hold`` (``std_msgs/msg/Bool``) is true
    whenever the platform must not move (:func:`must_hold`: no run running, or held for
    any reason: an abort, a stale link or odometry, a contest, a name taken) and
    ``/fedlab/LAB/NAME/run`` (``std_msgs/msg/String``) says the run's mode. Each is
    written when it changes and again every ``STATE_REPEAT`` seconds
    (:class:`Repeated`), and ``hold`` true once more when the bridge stops.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from federation.core.keys import AgentId
from federation.core.wire import Pose

__all__ = [
    "COMMON_FRAME",
    "LEVEL_TOLERANCE",
    "QUATERNION_TOLERANCE",
    "STATE_REPEAT",
    "OdometryError",
    "OdometryFields",
    "Repeated",
    "TransformFields",
    "agent_frame",
    "agent_topic",
    "dds_topic",
    "dds_type_name",
    "heading_quaternion",
    "host_stamp",
    "must_hold",
    "odometry_fields",
    "odometry_topic",
    "pose_from_odometry",
    "quaternion_heading",
    "ros_topic",
    "split_stamp",
    "stamp_seconds",
    "transform_fields",
]

COMMON_FRAME = "fedlab_common"
"""The TF frame of the federation's common frame (every agent's pose is in it)."""
QUATERNION_TOLERANCE = 1e-3
"""Largest accepted | |q| - 1 | of a received orientation."""
LEVEL_TOLERANCE = 0.05
"""Largest accepted roll or pitch of a received orientation, rad (air bearings are level)."""

STATE_REPEAT = 1.0
"""s: a joined platform's hold and run mode are written again this often, unchanged."""

_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class OdometryError(ValueError):
    """A received odometry that is not a planar pose fedlab can use."""


def ros_topic(name: str) -> str:
    """``name`` as an absolute ROS 2 topic name (``odom`` -> ``/odom``); ValueError if it
    is not a valid one."""
    text = name if name.startswith("/") else "/" + name
    tokens = text[1:].split("/")
    if not text[1:] or any(not _TOKEN.fullmatch(t) for t in tokens):
        raise ValueError(
            f"invalid ROS 2 topic {name!r}: use tokens of letters, digits and '_' "
            "separated by '/', none starting with a digit (e.g. /rover/odom)"
        )
    return text


def dds_topic(name: str) -> str:
    """The DDS topic ROS 2 uses for topic ``name``: ``/a/b`` -> ``rt/a/b``."""
    return "rt" + ros_topic(name)


def dds_type_name(ros_type: str) -> str:
    """ROS 2's DDS type name: ``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_``."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def odometry_topic(agent: AgentId) -> str:
    """The ROS 2 topic of an agent's odometry: ``/fedlab/LAB/NAME/odom``."""
    return agent_topic(agent, "odom")


def agent_topic(agent: AgentId, leaf: str) -> str:
    """An agent's ROS 2 topic ``/fedlab/LAB/NAME/<leaf>`` (``odom``, ``hold``, ``run``)."""
    return f"/fedlab/{agent.lab}/{agent.name}/{leaf}"


def must_hold(mode: str, hold: str | None) -> bool:
    """Whether a joined ROS 2 platform must not move: unless its run is running (waiting,
    armed, frozen, done, aborted) or while the agent holds it (``hold``)."""
    return mode != "running" or hold is not None


class Repeated:
    """When to write a value that a late ROS subscriber must learn and a silent writer
    must not hide: on a change, and again every ``every`` seconds of the caller's clock."""

    def __init__(self, every: float = STATE_REPEAT):
        if not every > 0:
            raise ValueError(f"every must be positive seconds, not {every!r}")
        self.every = every
        self._last: object = None
        self._at: float | None = None

    def due(self, value: object, now: float) -> bool:
        """Whether ``value`` is to be written at ``now`` (s); if so, it is taken as written."""
        if self._at is not None and value == self._last and now - self._at < self.every:
            return False
        self._last, self._at = value, now
        return True


def agent_frame(agent: AgentId) -> str:
    """An agent's TF frame: ``LAB/NAME``."""
    return f"{agent.lab}/{agent.name}"


def split_stamp(seconds: float) -> tuple[int, int]:
    """``builtin_interfaces/Time`` of ``seconds``: (sec, nanosec), nanosec in [0, 1e9)."""
    if not math.isfinite(seconds):
        raise ValueError(f"stamp must be finite seconds, not {seconds!r}")
    if not -(2**31) <= seconds <= 2**31 - 1:  # builtin_interfaces/Time's sec is an int32
        # (checked first: a stamp near 1e300 overflows in the product below)
        raise ValueError(f"stamp {seconds!r} s is beyond what ROS 2 time holds")
    total = round(seconds * 1e9)
    sec, nanosec = divmod(total, 1_000_000_000)
    return int(sec), int(nanosec)


def stamp_seconds(sec: int, nanosec: int) -> float:
    """Seconds of a ``builtin_interfaces/Time``."""
    return sec + nanosec * 1e-9


def host_stamp(
    t: float, sender_to_reference: float, reference_offset: float, mono_now: float, wall_now: float
) -> float:
    """Bridge host wall-clock time (s) of a pose stamped ``t`` on its sender's clock.

    ``sender_to_reference``: reference clock minus the sender's (0 on the reference);
    ``reference_offset``: reference clock minus the bridge's monotonic clock;
    ``mono_now``, ``wall_now``: the bridge's monotonic and wall clocks read together.
    """
    return wall_now + (t + sender_to_reference - reference_offset - mono_now)


def heading_quaternion(heading: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation by ``heading`` rad about z."""
    half = 0.5 * heading
    return 0.0, 0.0, math.sin(half), math.cos(half)


def quaternion_heading(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rad, in (-pi, pi]) of a unit, level quaternion; OdometryError otherwise."""
    values = (x, y, z, w)
    if not all(math.isfinite(v) for v in values):
        raise OdometryError(f"orientation {values} is not finite")
    norm = math.sqrt(sum(v * v for v in values))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise OdometryError(f"orientation {values} is not a unit quaternion (norm {norm:.6f})")
    x, y, z, w = (v / norm for v in values)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    if abs(roll) > LEVEL_TOLERANCE or abs(pitch) > LEVEL_TOLERANCE:
        raise OdometryError(
            f"orientation is not level: roll {roll:.3f} rad, pitch {pitch:.3f} rad "
            f"(at most {LEVEL_TOLERANCE} rad)"
        )
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@dataclass(frozen=True)
class OdometryFields:
    """The fields of one ``nav_msgs/msg/Odometry`` (covariances left zero: unknown)."""

    stamp: tuple[int, int]  # sec, nanosec
    frame_id: str
    child_frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # x, y, z, w
    linear: tuple[float, float, float]  # child (body) frame, m/s
    angular: tuple[float, float, float]  # rad/s


@dataclass(frozen=True)
class TransformFields:
    """The fields of one ``geometry_msgs/msg/TransformStamped``."""

    stamp: tuple[int, int]
    frame_id: str
    child_frame_id: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


def odometry_fields(agent: AgentId, pose: Pose, stamp: float) -> OdometryFields:
    """An agent's pose (common frame) as odometry stamped ``stamp`` (host wall clock, s)."""
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    linear = (c * pose.vx + s * pose.vy, -s * pose.vx + c * pose.vy, 0.0)
    if not all(math.isfinite(v) for v in linear):  # finite velocities, too large to turn
        raise ValueError(f"velocity ({pose.vx!r}, {pose.vy!r}) is not finite in the body frame")
    return OdometryFields(
        stamp=split_stamp(stamp),
        frame_id=COMMON_FRAME,
        child_frame_id=agent_frame(agent),
        position=(pose.x, pose.y, 0.0),
        orientation=heading_quaternion(pose.heading),
        linear=linear,
        angular=(0.0, 0.0, pose.omega),
    )


def transform_fields(agent: AgentId, pose: Pose, stamp: float) -> TransformFields:
    """The TF transform ``fedlab_common`` -> ``LAB/NAME`` of an agent's pose."""
    return TransformFields(
        stamp=split_stamp(stamp),
        frame_id=COMMON_FRAME,
        child_frame_id=agent_frame(agent),
        translation=(pose.x, pose.y, 0.0),
        rotation=heading_quaternion(pose.heading),
    )


def pose_from_odometry(
    position: tuple[float, float, float],
    orientation: tuple[float, float, float, float],
    linear: tuple[float, float, float],
    angular: tuple[float, float, float],
) -> Pose:
    """A received odometry's pose and twist (twist in the child frame) as a fedlab pose;
    :class:`OdometryError` if a value is not finite or the orientation is not level."""
    for what, values in (("position", position), ("linear", linear), ("angular", angular)):
        if not all(math.isfinite(v) for v in values):
            raise OdometryError(f"{what} {tuple(values)} is not finite")
    heading = quaternion_heading(*orientation)
    c, s = math.cos(heading), math.sin(heading)
    bx, by = linear[0], linear[1]
    vx, vy = c * bx - s * by, s * bx + c * by
    if not (math.isfinite(vx) and math.isfinite(vy)):
        # Finite in the body frame, too large to turn: an infinite pose would hold the
        # platform for good (nonfinite) on one sample.
        raise OdometryError(f"linear {tuple(linear)} is not finite in the common frame")
    return Pose(x=position[0], y=position[1], heading=heading, vx=vx, vy=vy, omega=angular[2])

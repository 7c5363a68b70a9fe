"""``fedlab bridge ros2``: the federation's poses on ROS 2, and a ROS 2 platform as an agent.

Real processes on loopback (routers, agents and the bridge through the ``labs`` fixture)
and a DDS reader and writer in the test. The ROS 2 types below are written here from
ROS 2's IDL (``rosidl``'s ``pkg::msg::dds_::Type_``), not imported from fedlab, so the test
checks the bridge against the types a ROS 2 node uses. Cyclone DDS is confined to the
loopback interface (no multicast; unicast discovery on 127.0.0.1) on a domain of this
test's own. The conversions, time passed in, are tested in tests/unit/bridge/.
"""

import json
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import pytest
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, DcpsEndpoint
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from inprocess import fedlab_here
from loopback import LEADER, STATUS_PERIOD, Agent, Labs, PoseTap

from federation.core import wire
from federation.core.keys import AgentId
from federation.fleet.launch import wait_for
from federation.runtime.control import START_IN_MIN

ROVER = "ros2lab/rover"
FOLLOWER = "rome/pinocchio"
ROVER_POSE = (1.5, -0.25, 0.3)  # x, y, heading the test's ROS 2 platform reports
# Published RIHS01 hashes (in the *__description.c that rosidl_generator_c writes into
# public ROS 2 workspaces): what a ROS 2 endpoint of each type announces in USER_DATA.
ODOMETRY_HASH = "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
TF_MESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


# -- ROS 2 types from their IDL (builtin_interfaces, std_msgs, geometry_msgs, nav_msgs, tf2_msgs)
@dataclass
class Time(IdlStruct, typename="builtin_interfaces.msg.dds_.Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs.msg.dds_.Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Vec3(IdlStruct, typename="geometry_msgs.msg.dds_.Vector3_"):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs.msg.dds_.Point_"):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Quat(IdlStruct, typename="geometry_msgs.msg.dds_.Quaternion_"):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass
class PoseMsg(IdlStruct, typename="geometry_msgs.msg.dds_.Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quat = field(default_factory=Quat)


Cov = Annotated[Sequence[float], t.array(t.float64, 36)]


@dataclass
class PoseCov(IdlStruct, typename="geometry_msgs.msg.dds_.PoseWithCovariance_"):
    pose: PoseMsg = field(default_factory=PoseMsg)
    covariance: Cov = field(default_factory=lambda: [0.0] * 36)


@dataclass
class TwistMsg(IdlStruct, typename="geometry_msgs.msg.dds_.Twist_"):
    linear: Vec3 = field(default_factory=Vec3)
    angular: Vec3 = field(default_factory=Vec3)


@dataclass
class TwistCov(IdlStruct, typename="geometry_msgs.msg.dds_.TwistWithCovariance_"):
    twist: TwistMsg = field(default_factory=TwistMsg)
    covariance: Cov = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs.msg.dds_.Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseCov = field(default_factory=PoseCov)
    twist: TwistCov = field(default_factory=TwistCov)


@dataclass
class TransformMsg(IdlStruct, typename="geometry_msgs.msg.dds_.Transform_"):
    translation: Vec3 = field(default_factory=Vec3)
    rotation: Quat = field(default_factory=Quat)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs.msg.dds_.TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: TransformMsg = field(default_factory=TransformMsg)


Transforms = Annotated[Sequence[TransformStamped], t.sequence(TransformStamped)]


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs.msg.dds_.TFMessage_"):
    transforms: Transforms = field(default_factory=list)


# -- fixtures ------------------------------------------------------------------------
LOOPBACK_DDS = (
    "<CycloneDDS><Domain Id='any'><General><Interfaces><NetworkInterface name='lo'/>"
    "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
    "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>20"
    "</MaxAutoParticipantIndex><Peers><Peer address='127.0.0.1'/></Peers></Discovery>"
    "</Domain></CycloneDDS>"
)


@pytest.fixture
def dds(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[DomainParticipant]:
    """A participant on a domain of this test's own, loopback only; the bridge processes
    started in the test inherit the same CYCLONEDDS_URI and ROS_DOMAIN_ID."""
    config = tmp_path / "cyclonedds.xml"
    config.write_text(LOOPBACK_DDS)
    # One domain per pytest process of a run: the parallel workers gw0 to gw3 take 11 to
    # 14, any other 10 (a domain shared by two tests at once mixes their bridges' topics).
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    domain = 10 + (int(worker[2:]) + 1 if worker.startswith("gw") else 0)
    monkeypatch.setenv("CYCLONEDDS_URI", config.as_uri())
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    participant = DomainParticipant(domain)
    yield participant
    del participant  # cyclonedds deletes the entity when its last reference goes


def start_bridge(labs: Labs, *args: str, who: str = "bridge") -> Agent:
    status = labs.tmp / "bridge.jsonl"
    argv = ["bridge", "ros2", *args, "--status-json", str(status), "--status-period", "0.5"]
    bridge = Agent(labs.fleet, "bridge-ros2", argv, who=who, status=status)
    bridge.start()
    return bridge


def yaw(q: Quat) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def matching(samples: list[wire.PoseSample], odom: Odometry) -> wire.PoseSample | None:
    """The published sample whose pose this odometry carries (1e-9 tolerance)."""
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    for sample in reversed(samples):
        pose = sample.pose
        if (
            abs(pose.x - p.x) <= 1e-9
            and abs(pose.y - p.y) <= 1e-9
            and abs(math.remainder(pose.heading - yaw(q), math.tau)) <= 1e-9
        ):
            return sample
    return None


# -- tests ---------------------------------------------------------------------------
@pytest.mark.integration
def test_every_agent_is_on_ros2_as_odometry_and_tf(labs: Labs, dds: DomainParticipant) -> None:
    pair = labs.pair()
    # A simulated KNATTE: its navigated pose is noisy, so every sample differs.
    leader = labs.leader(pair.kiruna, "--platform", "knatte")
    follower = labs.follower(pair.rome)
    bridge = start_bridge(labs, "-e", pair.rome.endpoint)
    # A start-up wait, not a latency: with other suites on the 2 cores, five processes
    # starting at once were seen to take 10 s to come up (routers included).
    leader.wait_status(timeout=30)
    tap = PoseTap(pair.kiruna.endpoint, f"fedlab/default/{LEADER}/pose")
    try:
        follower.wait_samples(LEADER, 5, timeout=15)
        # The bridge publishes once it knows the leader's place on reference time.
        assert wait_for(lambda: "kiruna/knatte on ROS 2 topic" in bridge.log(), timeout=15), (
            bridge.log()[-2000:]
        )

        odom_topic = Topic(dds, "rt/fedlab/kiruna/knatte/odom", Odometry)
        tf_topic = Topic(dds, "rt/tf", TFMessage)
        reliable = Qos(
            Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10)
        )
        odom_reader = DataReader(dds, odom_topic, reliable)
        tf_reader = DataReader(dds, tf_topic, reliable)
        created = time.monotonic()
        received: list[Odometry] = []

        def got_odometry() -> bool:
            received.extend(s for s in odom_reader.take(N=100) if isinstance(s, Odometry))
            return bool(received)

        assert wait_for(got_odometry, timeout=1.0, interval=0.01), "no odometry within 1 s"
        first_after = time.monotonic() - created
        odom = received[0]

        # The pose the leader published, in the common frame, within 1e-9. The tap's
        # Zenoh callback and the DDS reader run on threads of their own in this process:
        # the sample may reach the tap after its odometry reached the reader.
        found: list[wire.PoseSample] = []

        def tapped() -> bool:
            sample = matching(tap.received(), odom)
            found[:] = [] if sample is None else [sample]
            return bool(found)

        assert wait_for(tapped, timeout=2.0, interval=0.01), (odom, tap.received()[-3:])
        sample = found[0]
        assert odom.header.frame_id == "fedlab_common"
        assert odom.child_frame_id == "kiruna/knatte"
        assert odom.pose.pose.position.z == 0.0
        q = odom.pose.pose.orientation
        assert math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2) == pytest.approx(1.0, abs=1e-12)
        # Twist in the child (body) frame: the common-frame velocity rotated by -heading.
        h = sample.pose.heading
        v = odom.twist.twist
        assert v.linear.x == pytest.approx(
            math.cos(h) * sample.pose.vx + math.sin(h) * sample.pose.vy, abs=1e-9
        )
        assert v.linear.y == pytest.approx(
            -math.sin(h) * sample.pose.vx + math.cos(h) * sample.pose.vy, abs=1e-9
        )
        assert v.angular.z == pytest.approx(sample.pose.omega, abs=1e-9)

        # Stamped on reference time (the leader's clock) mapped to this host's wall clock.
        line = leader.latest()
        leader_minus_host = line["t_exec"] - line["host_monotonic"]
        wall_minus_mono = time.time() - time.monotonic()
        expected = sample.t - leader_minus_host + wall_minus_mono
        stamp = odom.header.stamp.sec + odom.header.stamp.nanosec * 1e-9
        assert abs(stamp - expected) < 0.005, (stamp, expected)

        # TF: fedlab_common -> kiruna/knatte, and the follower's frame too.
        frames: dict[str, TransformStamped] = {}

        def got_frames() -> bool:
            for message in tf_reader.take(N=100):
                if isinstance(message, TFMessage):
                    frames.update({tf.child_frame_id: tf for tf in message.transforms})
            return {"kiruna/knatte", FOLLOWER} <= set(frames)

        assert wait_for(got_frames, timeout=3, interval=0.02), sorted(frames)
        tf = frames["kiruna/knatte"]
        assert tf.header.frame_id == "fedlab_common"
        as_odometry = _as_odometry(tf)
        assert wait_for(
            lambda: matching(tap.received(), as_odometry) is not None, timeout=2.0, interval=0.01
        ), (tf, tap.received()[-3:])
        print(f"first odometry {first_after * 1e3:.0f} ms after the reader was created")

        # The type hashes ROS 2 (Iron and later) announces, in the writers' USER_DATA.
        announced = publications(dds, {"rt/fedlab/kiruna/knatte/odom", "rt/tf"})
        assert announced == {
            "rt/fedlab/kiruna/knatte/odom": f"typehash={ODOMETRY_HASH};".encode(),
            "rt/tf": f"typehash={TF_MESSAGE_HASH};".encode(),
        }
    finally:
        tap.close()
    assert bridge.alive()


def publications(dds: DomainParticipant, topics: set[str]) -> dict[str, bytes]:
    """The USER_DATA of the remote writers on ``topics``, from DDS discovery (bounded)."""
    reader = BuiltinDataReader(dds, BuiltinTopicDcpsPublication)
    found: dict[str, bytes] = {}

    def seen() -> bool:
        for endpoint in reader.take(N=100):
            if isinstance(endpoint, DcpsEndpoint) and endpoint.topic_name in topics:
                found[endpoint.topic_name] = endpoint.qos[Policy.Userdata].data
        return set(found) == topics

    assert wait_for(seen, timeout=3, interval=0.05), found
    return found


def _as_odometry(tf: TransformStamped) -> Odometry:
    """A transform's pose in an odometry, to compare with the published samples."""
    tr = tf.transform.translation
    return Odometry(
        pose=PoseCov(PoseMsg(Point(tr.x, tr.y, tr.z), tf.transform.rotation)),
    )


class OdometryWriter:
    """The test's ROS 2 platform: odometry at 20 Hz on ``topic`` while ``running``."""

    def __init__(self, participant: DomainParticipant, topic: str):
        qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepLast(10))
        self.writer = DataWriter(participant, Topic(participant, topic, Odometry), qos)
        self.running = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.sent = 0

    def _run(self) -> None:
        x, y, heading = ROVER_POSE
        q = Quat(0.0, 0.0, math.sin(heading / 2), math.cos(heading / 2))
        for _ in range(20 * 120):  # bounded: two minutes at 20 Hz
            if self._stop.wait(0.05):
                return
            if not self.running.is_set():
                continue
            now = time.time()
            stamp = Time(int(now), int((now % 1) * 1e9))
            self.writer.write(
                Odometry(
                    Header(stamp, "odom"), "base_link",
                    PoseCov(PoseMsg(Point(x, y, 0.0), q)), TwistCov(),
                )
            )  # fmt: skip
            self.sent += 1

    def start(self) -> None:
        self.running.set()
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)


@pytest.mark.integration
def test_a_ros2_platform_joins_and_a_fedlab_follower_follows_it(
    labs: Labs, dds: DomainParticipant
) -> None:
    pair = labs.pair()
    platform = OdometryWriter(dds, "rt/rover/odom")
    platform.start()
    rover = start_bridge(
        labs, "--as", ROVER, "--odom", "/rover/odom", "--odom-timeout", "0.5",
        "-e", pair.kiruna.endpoint, who=ROVER,
    )  # fmt: skip
    follower = labs.follower(pair.rome, follow=ROVER)
    try:
        # It is an agent: sync queryable (the follower's samples), pose and status.
        follower.wait_samples(ROVER, 10, timeout=20)
        line = follower.until(
            lambda s: s["pose_age"] is not None and abs(s["pose"][2] - ROVER_POSE[2]) < 1e-6,
            timeout=10,
            what="the follower on the rover's heading",
        )
        assert line["hold"] is None
        status = rover.until(lambda s: s["hold"] is None, timeout=5, what="rover status")
        assert status["agent"] == ROVER and status["platform"] == "ros2:/rover/odom"
        assert status["pose"][:3] == pytest.approx(list(ROVER_POSE), abs=1e-12)
        assert status["counters"]["odom_received"] > 0
        holds = status["counters"].get("odom_stale_holds", 0)  # one before the first odometry

        # The topic goes stale: the rover holds and publishes no pose, its follower holds.
        platform.running.clear()
        rover.until(lambda s: s["hold"] == "source_stale", timeout=3, what="the rover on hold")
        follower.until(lambda s: s["hold"] == "stale", timeout=3, what="the follower on hold")
        # Odometry again: both released.
        platform.running.set()
        rover.until(lambda s: s["hold"] is None, timeout=3, what="the rover released")
        follower.until(lambda s: s["hold"] is None, timeout=5, what="the follower released")
        assert rover.latest()["counters"]["odom_stale_holds"] == holds + 1
    finally:
        platform.close()
    assert rover.alive()


@dataclass
class BoolMsg(IdlStruct, typename="std_msgs.msg.dds_.Bool_"):
    data: bool = False


@dataclass
class StringMsg(IdlStruct, typename="std_msgs.msg.dds_.String_"):
    data: str = ""


class StateReader:
    """A ROS node's view of the joined platform's ``hold`` and ``run`` topics, subscribed
    late with transient local (it gets the current value): every value, timed on arrival."""

    def __init__(self, participant: DomainParticipant, agent: str):
        qos = Qos(
            Policy.Reliability.Reliable(duration(seconds=1)),
            Policy.History.KeepLast(10),
            Policy.Durability.TransientLocal,
        )
        base = f"rt/fedlab/{agent}"
        self.hold_reader = DataReader(participant, Topic(participant, f"{base}/hold", BoolMsg), qos)
        self.run_reader = DataReader(participant, Topic(participant, f"{base}/run", StringMsg), qos)
        self.holds: list[tuple[float, bool]] = []
        self.runs: list[str] = []

    def read(self) -> None:
        # Timed by the writer's source timestamp (wall clock), on this host's monotonic one.
        to_monotonic = time.monotonic() - time.time()
        self.holds += [
            (s.sample_info.source_timestamp * 1e-9 + to_monotonic, s.data)
            for s in self.hold_reader.take(N=100)
            if isinstance(s, BoolMsg)
        ]
        self.runs += [s.data for s in self.run_reader.take(N=100) if isinstance(s, StringMsg)]

    def until(self, hold: bool, run: str | None, timeout: float) -> float:
        """Poll every 5 ms until the last hold is ``hold`` (and the run mode ``run``); when
        that hold was first written (this host's monotonic clock)."""

        def met() -> bool:
            self.read()
            if not self.holds or self.holds[-1][1] is not hold:
                return False
            return run is None or (bool(self.runs) and self.runs[-1] == run)

        said = (hold, run, self.holds[-3:], self.runs[-3:])
        assert wait_for(met, timeout=timeout, interval=0.005), said
        first = len(self.holds) - 1
        while first > 0 and self.holds[first - 1][1] is hold:
            first -= 1
        return self.holds[first][0]


@pytest.mark.integration
@pytest.mark.timing
def test_a_joined_ros2_platform_is_told_to_hold_unless_its_run_runs(
    labs: Labs, dds: DomainParticipant
) -> None:
    """The joined platform is a participant of a ctl run (--reference, --wait-start,
    --runs-dir): ROS is told to hold while it waits, to move once the run starts, to hold
    within 200 ms of an abort, and to hold when the bridge stops mid-run. The bridge
    locks its estimate 2 s after its first exchange (--sync-window 2, as QUICK_LOCK: a
    start needs a locked estimate, not the paper's 10 s sync phase); each start is
    announced the least ctl allows ahead (START_IN_MIN); ctl runs in the test's process
    (the hold is timed from the instant ctl stamps on sending the abort) and discovers
    for two status periods."""
    pair = labs.pair()
    runs = labs.tmp / "runs"
    leader = labs.leader(pair.kiruna, "--wait-start", "--runs-dir", str(runs))
    platform = OdometryWriter(dds, "rt/rover/odom")
    platform.start()
    rover = start_bridge(
        labs, "--as", ROVER, "--odom", "/rover/odom", "--reference", LEADER, "--wait-start",
        "--runs-dir", str(runs), "--sync-window", "2", "-e", pair.rome.endpoint, who=ROVER,
    )  # fmt: skip
    try:
        ready = lambda s: (s.get("ready") or {}).get("reference_locked") and s["hold"] == "waiting"  # noqa: E731
        rover.until(ready, timeout=30, what="the rover locked on the leader's clock")
        leader.wait_status(timeout=15)
        state = StateReader(dds, ROVER)
        state.until(True, "waiting", timeout=3)  # a late subscriber learns it at once

        # ctl hears every agent out there within two of their status periods (0.5 s
        # each: the leader's STATUS_PERIOD, the rover's --status-period in start_bridge)
        # rather than in its 1.5 s default, sized for agents at 1 s.
        discover = f"{2 * STATUS_PERIOD:g}"

        def ctl(*args: str) -> dict[str, Any]:
            done = fedlab_here(
                "ctl", *args, "--reference", LEADER, "--discover", discover, "--json",
                "-e", pair.kiruna.endpoint,
            )  # fmt: skip
            assert done.returncode == 0, done.stdout + done.stderr
            return json.loads(done.stdout)  # type: ignore[no-any-return]

        soon = f"{START_IN_MIN:g}"
        ctl("start", "--in", soon, "--duration", "60")
        state.until(False, "running", timeout=10)
        sent = ctl("abort")["sent_monotonic"]  # this host's clock
        held = state.until(True, "aborted", timeout=5)
        print(f"hold written to ROS {(held - sent) * 1e3:.1f} ms after ctl sent abort")
        assert 0 <= held - sent < 0.200  # the next control step (20 Hz) writes it

        ctl("reset")
        state.until(True, "waiting", timeout=5)
        ctl("start", "--in", soon, "--duration", "60")
        state.until(False, "running", timeout=10)
        rover.stop()  # mid-run: the last word to ROS is hold
        state.until(True, None, timeout=5)
        assert rover.latest()["counters"]["ros_hold_written"] >= 4
    finally:
        platform.close()


def test_types_here_are_named_as_ros2_names_them() -> None:
    """The test's own types carry ROS 2's DDS names (what the bridge must match)."""
    names: dict[type[Any], str] = {
        Odometry: "nav_msgs::msg::dds_::Odometry_",
        TFMessage: "tf2_msgs::msg::dds_::TFMessage_",
    }
    for cls, name in names.items():
        assert cls.__idl__.idl_transformed_typename == name  # type: ignore[attr-defined]


def test_a_second_publisher_on_a_joined_platforms_odometry_is_not_flown_on(
    dds: DomainParticipant,
) -> None:
    """Two writers on the platform's odometry topic (another robot's node, a bag played
    on it): whose pose is it? Before, each step took whichever came last, the pose
    jumping 10 m and 3 rad back and forth, nothing counted. Now nothing is taken while
    two publish, and the platform goes stale (held)."""
    from federation.bridge import ros2 as bridge
    from federation.bridge import ros2_core as conv
    from federation.bridge import ros2_types

    topic = Topic(dds, conv.dds_topic("/rover/odom"), ros2_types.Odometry)
    reader = DataReader(dds, topic, bridge.odometry_reader_qos())
    real = DataWriter(dds, topic, bridge.odometry_writer_qos())
    platform = bridge.OdometryPlatform(reader, timeout=0.5)
    rover = AgentId.parse("ros2lab/rover")

    def odometry(x: float, heading: float) -> Any:
        fields = conv.odometry_fields(rover, wire.Pose(x, 0.0, heading), time.time())
        return ros2_types.odometry_message(fields)

    def steps(n: int, other: DataWriter | None = None) -> list[float]:
        seen = []
        for _ in range(n):  # bounded: n control steps at 20 Hz
            real.write(odometry(0.0, 0.0))
            if other is not None:
                other.write(odometry(10.0, 3.0))
            time.sleep(0.05)
            seen.append(platform.step(0, 0, 0).x)
        return seen

    assert wait_for(lambda: len(reader.get_matched_publications()) == 1, timeout=5)
    assert set(steps(4)) == {0.0} and not platform.stale
    other = DataWriter(dds, topic, bridge.odometry_writer_qos())
    assert wait_for(lambda: len(reader.get_matched_publications()) == 2, timeout=5)
    seen = steps(20, other)
    assert 10.0 not in seen and platform.stale, seen
    assert platform.counters["odom_contested"] >= 20, platform.counters
    assert platform.last_rejection == "2 publishers on the topic"
    del other  # gone: the one writer's odometry is taken again
    # Taken again once the other's last odometry is older than the timeout (0.5 s).
    assert wait_for(lambda: steps(1) == [0.0] and not platform.stale, timeout=5, interval=0)
    assert not platform.stale and platform.pose.x == 0.0


_ODOMETRY_NODE = """
import sys, time
from cyclonedds.domain import DomainParticipant
from cyclonedds.topic import Topic
from cyclonedds.pub import DataWriter
from federation.bridge import ros2 as bridge, ros2_core as conv, ros2_types
from federation.core import wire
from federation.core.keys import AgentId
participant = DomainParticipant(int(sys.argv[1]))
topic = Topic(participant, conv.dds_topic("/rover/odom"), ros2_types.Odometry)
writer = DataWriter(participant, topic, bridge.odometry_writer_qos())
rover = AgentId.parse("ros2lab/rover")
for _ in range(1200):  # bounded: 60 s at 20 Hz
    pose = wire.Pose(1.0, 0.0, 0.0)
    writer.write(ros2_types.odometry_message(conv.odometry_fields(rover, pose, time.time())))
    time.sleep(0.05)
"""


def test_a_robots_odometry_node_killed_and_restarted_is_taken_again_at_once(
    dds: DomainParticipant,
) -> None:
    """The dead node's writer stays matched until its DDS lease ends (10 s and more):
    counted as a second publisher, it had held the platform all that time."""
    from federation.bridge import ros2 as bridge
    from federation.bridge import ros2_core as conv
    from federation.bridge import ros2_types

    topic = Topic(dds, conv.dds_topic("/rover/odom"), ros2_types.Odometry)
    reader = DataReader(dds, topic, bridge.odometry_reader_qos())
    platform = bridge.OdometryPlatform(reader, timeout=0.5)
    domain = str(dds.domain_id)

    def node() -> subprocess.Popen[bytes]:
        return subprocess.Popen([sys.executable, "-c", _ODOMETRY_NODE, domain])

    def stale() -> bool:
        platform.step(0, 0, 0)
        return platform.stale

    def fresh(seconds: float) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:  # bounded by seconds
            platform.step(0, 0, 0)
            if not platform.stale:
                return True
            time.sleep(0.05)
        return False

    nodes = [node()]
    try:
        assert fresh(20), platform.counters  # the first node up and heard
        nodes[0].kill()
        nodes[0].wait(10)
        # Its last odometry ages out (0.5 s): the platform stale, the dead writer matched.
        assert wait_for(stale, timeout=5), platform.counters
        nodes.append(node())  # started again: a new writer
        assert fresh(5.0), (platform.last_rejection, platform.counters)
        assert len(reader.get_matched_publications()) >= 1
    finally:
        for n in nodes:
            n.kill()
            n.wait(10)

"""``fedlab bridge ros2``: the federation on ROS 2 (DDS), and a ROS 2 platform in the federation.

::

    federation (Zenoh)  --- poses, status, sync --->  bridge  --- Odometry, /tf --->  ROS 2 (DDS)
                        <-- LAB/NAME as an agent ---          <-- --odom TOPIC ---

Federation to ROS 2 (:class:`FederationToRos`)
    Every agent's pose sample becomes a ``nav_msgs/msg/Odometry`` on
    ``/fedlab/LAB/NAME/odom`` (frame ``fedlab_common``, child ``LAB/NAME``; twist in the
    child frame, as ROS has it) and a transform ``fedlab_common -> LAB/NAME`` in a
    ``tf2_msgs/msg/TFMessage`` on ``/tf``. Stamps are the federation's reference time
    mapped to this host's wall clock (:mod:`federation.bridge.ros2_core`): the sender's
    reference offset from its status, this bridge's offset to the reference from its own
    sync queries (every 0.1 s). Until both are known a sample is not published (counted
    in ``odom_unmapped``): a pose with a wrong stamp would mislead a ROS consumer.
A ROS 2 platform joins (``--as LAB/NAME --odom TOPIC``, :class:`Ros2Agent`)
    An :class:`~federation.runtime.agent.AgentRuntime` whose platform is the latest
    received odometry (:class:`OdometryPlatform`): sync queryable, liveliness token, pose
    and status like any agent's. With no valid odometry for ``odom_timeout`` seconds it
    holds (status ``hold: "stale"``) and publishes no pose, so its followers see the
    link go quiet and hold too (fail closed); a fresh odometry releases it. A sample
    that is not finite or not level is dropped and counted (``odom_malformed``).
    Its actuators are ROS's to command, so what the federation decided goes to ROS
    (:class:`RunStateToRos`): ``/fedlab/LAB/NAME/hold`` (``std_msgs/msg/Bool``, true
    while it must not move: no run running, an abort, a stale link or odometry, ...)
    and ``/fedlab/LAB/NAME/run`` (``std_msgs/msg/String``, the run's mode), written at
    the control step that sees a change, again every second, and ``hold`` true when
    the bridge stops. A ROS node that moves the platform should stop on ``hold`` true,
    and on no ``hold`` for more than a second or two (the bridge gone). With
    ``--wait-start`` it waits for ``fedlab ctl start`` as other agents do.
QoS, as ROS 2 users expect
    Odometry and ``/tf`` are written reliable, keep-last (10 and 100, ``tf2_ros``'s
    depth), volatile: a ROS 2 subscriber with the default profile or the sensor-data
    profile matches. The platform's odometry is read best effort, which matches a
    reliable or a best-effort publisher. Samples are XCDR1 (what ROS 2's middlewares
    exchange). The DDS domain is ``--domain-id`` (ROS_DOMAIN_ID's meaning); Cyclone DDS
    reads its network configuration from ``CYCLONEDDS_URI`` as it does under ROS 2.
    Every reader and writer announces its type's hash in USER_DATA
    (``typehash=RIHS01_...;``, :mod:`federation.bridge.ros2_typehash`), as ROS 2 nodes
    since Iron do.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import zenoh
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration
from pydantic import ValidationError

from agents.guidance import Track
from agents.kinematic import KinematicPlatform
from federation.bridge import ros2_core as conv
from federation.bridge.ros2_typehash import BOOL, ODOMETRY, STRING_MESSAGE, TF_MESSAGE, user_data
from federation.bridge.ros2_types import (
    Bool,
    Odometry,
    String,
    TFMessage,
    odometry_message,
    tf_message,
)
from federation.core import keys, wire
from federation.core.counters import Count
from federation.core.estimators import make_estimator
from federation.core.holds import Hold, Trigger
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.agent import AgentRuntime, RateLimitedLog
from federation.runtime.session import undeclare_all
from federation.runtime.syncglue import Answer, SyncQuerier
from schemas.config import AgentConfig
from schemas.messages import Status

__all__ = [
    "AgentLoopStopped",
    "FederationToRos",
    "OdometryPlatform",
    "Ros2Agent",
    "RunStateToRos",
    "odometry_reader_qos",
    "odometry_writer_qos",
    "run_ros2_bridge",
    "state_writer_qos",
    "tf_writer_qos",
]

log = logging.getLogger("fedlab.bridge.ros2")

SYNC_PERIOD = 0.1  # s between the bridge's sync queries to the reference
SYNC_TIMEOUT = 0.5  # s
STATUS_MAX_BYTES = 1 << 20
MAX_CLOCK_OFFSET = 1e9  # s: an agent's reference minus its own clock, at most (31 years)
_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)


def _type_hash(name: str) -> Any:
    """USER_DATA ``typehash=RIHS01_...;``, as ROS 2 (Iron and later) announces its types."""
    return Policy.Userdata(data=user_data(name))


def odometry_writer_qos() -> Qos:
    """ROS 2's default profile: reliable, keep last 10, volatile; Odometry's type hash."""
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.History.KeepLast(10),
        Policy.Durability.Volatile,
        _XCDR1,
        _type_hash(ODOMETRY),
    )


def tf_writer_qos() -> Qos:
    """``tf2_ros``'s broadcaster: reliable, keep last 100, volatile; TFMessage's type hash."""
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.History.KeepLast(100),
        Policy.Durability.Volatile,
        _XCDR1,
        _type_hash(TF_MESSAGE),
    )


def state_writer_qos(type_name: str) -> Qos:
    """A joined platform's hold and run mode: reliable, transient local, keep last 1, so
    a ROS node that subscribes late (with transient local) gets the current value."""
    return Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.History.KeepLast(1),
        Policy.Durability.TransientLocal,
        _XCDR1,
        _type_hash(type_name),
    )


def odometry_reader_qos() -> Qos:
    """Best effort, keep last 10: matches reliable and best-effort publishers."""
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(10), _type_hash(ODOMETRY))


class FederationToRos:
    """Every agent's pose from Zenoh to ROS 2 odometry and TF. ``start()``, ``step()``
    repeatedly, ``close()`` before the session closes."""

    def __init__(
        self,
        session: zenoh.Session,
        participant: DomainParticipant,
        federation: str = keys.DEFAULT_FEDERATION,
        monotonic: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ):
        self.session = session
        self.participant = participant
        self.federation = keys.validate_name(federation, "federation name")
        self.monotonic, self.wall = monotonic, wall
        self.counters: Counter[Count] = Counter()
        self.rejects = RateLimitedLog(log)
        self.wake = threading.Event()  # set by a pose arriving
        self._lock = threading.Lock()
        self._pending: dict[AgentId, wire.PoseSample] = {}  # newest unpublished sample per agent
        self._to_reference: dict[AgentId, float] = {}  # reference clock minus the agent's
        self._reference_of: dict[AgentId, AgentId] = {}  # each agent's reference, by status
        self.reference: AgentId | None = None
        self.link: SyncClient | None = None  # this bridge's sync with the reference
        self._querier: SyncQuerier | None = None
        self._next_sync = 0.0
        self._writers: dict[AgentId, DataWriter[Odometry]] = {}
        self._tf: DataWriter[TFMessage] | None = None
        self._declared: list[Any] = []

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> None:
        callback = zenoh.handlers.Callback
        fed = self.federation
        tf_topic = Topic(self.participant, conv.dds_topic("/tf"), TFMessage)
        self._tf = DataWriter(self.participant, tf_topic, tf_writer_qos())
        self._declared.append(
            self.session.declare_subscriber(
                keys.all_of(fed, "pose"), callback(self._on_pose, indirect=False)
            )
        )
        self._declared.append(
            self.session.declare_subscriber(
                keys.all_of(fed, "status"), callback(self._on_status, indirect=False)
            )
        )

    def close(self) -> None:
        undeclare_all(self._declared)

    # -- Zenoh callbacks: quick, never raise ----------------------------------------------
    def _on_pose(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            if parsed is None:
                self.counters[Count.POSE_FOREIGN_KEY] += 1
                return
            try:
                decoded = wire.decode_pose(sample.payload.to_bytes())
            except wire.DecodeError as error:
                self.counters[Count.POSE_MALFORMED] += 1
                self.rejects("pose sample", f"{sample.key_expr}: {error}")
                return
            with self._lock:
                self._pending[parsed[0]] = decoded
            self.wake.set()
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            payload = sample.payload.to_bytes()
            if parsed is None or len(payload) > STATUS_MAX_BYTES:
                self.counters[Count.STATUS_MALFORMED] += 1
                return
            try:
                status = Status.model_validate_json(payload)
                reference = AgentId.parse(status.reference)
            except (ValidationError, ValueError) as error:
                self.counters[Count.STATUS_MALFORMED] += 1
                self.rejects("status", f"{sample.key_expr}: {error}")
                return
            if status.agent != str(parsed[0]):
                self.counters[Count.STATUS_MALFORMED] += 1
                return
            offset = None if status.t_sim is None else status.t_sim - status.t_exec
            if offset is not None and not abs(offset) <= MAX_CLOCK_OFFSET:  # NaN too
                # Its poses would be stamped at no time ROS can hold (a crash, once).
                self.counters[Count.STATUS_MALFORMED] += 1
                self.rejects("status", f"{sample.key_expr}: clock offset {offset!r} s")
                return
            with self._lock:
                self._reference_of[parsed[0]] = reference
                if offset is not None:
                    self._to_reference[parsed[0]] = offset
                else:
                    self._to_reference.pop(parsed[0], None)
        except Exception:
            log.exception("status sample on %s failed", sample.key_expr)

    def _on_answer(self, link: SyncClient, answer: Answer) -> None:
        """A reply of the reference, taken by ``link`` if it is still the one in use."""
        if not answer.ok:
            self.counters[Count.SYNC_REPLY_ERRORS] += 1
            return
        with self._lock:
            if link is self.link:
                link.receive(answer.payload(), answer.t3)

    def _read(self) -> tuple[float, float]:
        now = self.monotonic()
        return now, now

    # -- the bridge's loop -------------------------------------------------------------
    def sync(self, now: float) -> None:
        """Follow the federation's reference (named by most statuses) and query it."""
        with self._lock:
            named = Counter(self._reference_of.values()).most_common()
            reference = min(named, key=lambda item: (-item[1], item[0]))[0] if named else None
            if reference != self.reference:
                self.reference = reference
                self.link = None if reference is None else SyncClient(make_estimator("clockfilter"))
                if self._querier is not None:
                    self._undeclare_querier()
                if reference is not None:
                    log.info("reference time is %s's clock", reference)
            link = self.link
        if link is None or self.reference is None or now < self._next_sync:
            return
        self._next_sync = now + SYNC_PERIOD
        try:
            if self._querier is None:
                self._querier = SyncQuerier(
                    self.session, keys.agent_key(self.federation, self.reference, "sync"),
                    SYNC_TIMEOUT, self._read, functools.partial(self._on_answer, link),
                )  # fmt: skip
            with self._lock:
                payload = link.request(self.monotonic())
            self._querier.request(payload)
        except Exception as error:  # session closing
            log.warning("sync request to %s failed: %s", self.reference, error)

    def _undeclare_querier(self) -> None:
        if self._querier is not None:
            self._querier.close()
        self._querier = None

    def reference_offset(self, now: float) -> float | None:
        """Reference clock minus this bridge's monotonic clock; None until synced."""
        with self._lock:
            return None if self.link is None else self.link.offset_at(now)

    def publish(self) -> int:
        """Write every pose received since the last call; returns how many were written."""
        with self._lock:
            pending, self._pending = self._pending, {}
            to_reference = dict(self._to_reference)
        if not pending:
            return 0
        mono, wall = self.monotonic(), self.wall()
        theta = self.reference_offset(mono)
        transforms = []
        for agent, sample in sorted(pending.items()):
            r = to_reference.get(agent)
            if theta is None or r is None:
                self.counters[Count.ODOM_UNMAPPED] += 1
                continue
            try:
                stamp = conv.host_stamp(sample.t, r, theta, mono, wall)
                odometry = conv.odometry_fields(agent, sample.pose, stamp)
                transform = conv.transform_fields(agent, sample.pose, stamp)
            except ValueError as error:  # no ROS time, or a twist not finite once turned
                # One agent's bad sample: skipped, the others' written (raised, it would
                # stop the bridge, and every joined platform with it).
                self.counters[Count.ODOM_UNWRITABLE] += 1
                self.rejects("pose", f"{agent}: {error}")
                continue
            writer = self._writers.get(agent)
            if writer is None:
                topic = Topic(
                    self.participant, conv.dds_topic(conv.odometry_topic(agent)), Odometry
                )
                writer = self._writers[agent] = DataWriter(
                    self.participant, topic, odometry_writer_qos()
                )
                log.info("%s on ROS 2 topic %s", agent, conv.odometry_topic(agent))
            writer.write(odometry_message(odometry))
            transforms.append(transform)
            self.counters[Count.ODOM_PUBLISHED] += 1
        if transforms and self._tf is not None:
            self._tf.write(tf_message(transforms))
            self.counters[Count.TF_PUBLISHED] += 1
        return len(transforms)

    def step(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for poses; sync with the reference; publish."""
        self.wake.wait(timeout)
        self.wake.clear()
        self.sync(self.monotonic())
        self.publish()


ODOM_CLOCK_TOLERANCE = 2.0
"""s: a joined platform's odometry stamped further than this from the bridge host's wall
clock is not taken (an hour-old bag replayed, a node on simulated time): keep the ROS
hosts' clocks synchronized (NTP, chrony)."""


class OdometryPlatform(KinematicPlatform):
    """A platform whose pose is the latest valid odometry read from ``reader``.

    ``stale``: no valid odometry for ``timeout`` seconds of ``clock`` (or none yet).
    Held (an abort), the pose still follows the odometry: it is a measurement, and a ROS
    platform's actuators are commanded in ROS, not here.

    Valid is: finite, level, stamped within :data:`ODOM_CLOCK_TOLERANCE` of ``wall`` and
    after the last one taken (an older sample, or the same one sent again, refreshes
    nothing: a stuck node re-sending its last pose goes stale), in the frames of the
    first one taken (``header.frame_id`` -> ``child_frame_id``: another robot's on the
    same topic, or the odometry of another frame, is not), and while one writer is heard
    on the topic within ``timeout`` (two sources of one platform's pose: whose is it?).
    Each sample refused is counted by kind; :attr:`last_rejection` says why, for the
    hold's log line."""

    def __init__(
        self,
        reader: DataReader[Odometry],
        timeout: float,
        rate: float = 20.0,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ):
        super().__init__(rate=rate)
        if not timeout > 0:
            raise ValueError(f"odometry timeout must be positive seconds, not {timeout!r}")
        self.reader, self.timeout, self.clock, self.wall = reader, timeout, clock, wall
        self.received_at: float | None = None
        self.frames: tuple[str, str] | None = None  # (frame_id, child_frame_id), first taken
        self.stamp: float | None = None  # the last taken sample's header stamp (s)
        self.last_rejection: str | None = None
        self._writers: dict[object, float] = {}  # writer -> clock time last heard
        self.counters: Counter[Count] = Counter()
        self.rejects = RateLimitedLog(log)

    @property
    def stale(self) -> bool:
        return self.received_at is None or self.clock() - self.received_at > self.timeout

    @property
    def has_fix(self) -> bool:
        """Whether a valid odometry sample has been taken: before, the pose is no
        measurement (once taken, it stays one; :attr:`stale` says when it grows old)."""
        return self.received_at is not None

    def _refuse(self, kind: Count, why: str) -> None:
        self.counters[kind] += 1
        self.last_rejection = why
        self.rejects(kind, why)

    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> wire.Pose:
        samples = [s for s in self.reader.take(N=100) if isinstance(s, Odometry)]
        if not samples:  # (an instance state change carries no data)
            return self.pose
        now = self.clock()
        for sample in samples:
            # The writers heard within the timeout: a node killed and started again is a
            # new writer, but the dead one, silent, drops out (matched writers would
            # count it until its DDS lease ended, 10 s and more).
            info = getattr(sample, "sample_info", None)
            self._writers[getattr(info, "publication_handle", None)] = now
            self._writers = {w: at for w, at in self._writers.items() if now - at <= self.timeout}
            if len(self._writers) > 1:
                self._refuse(Count.ODOM_CONTESTED, f"{len(self._writers)} publishers on the topic")
                continue
            frames = (sample.header.frame_id, sample.child_frame_id)
            if self.frames is not None and frames != self.frames:
                self._refuse(
                    Count.ODOM_FOREIGN_FRAME,
                    f"odometry of {frames[0]!r} -> {frames[1]!r}, not the "
                    f"{self.frames[0]!r} -> {self.frames[1]!r} first taken",
                )
                continue
            stamp = conv.stamp_seconds(sample.header.stamp.sec, sample.header.stamp.nanosec)
            off = stamp - self.wall()
            if not abs(off) <= ODOM_CLOCK_TOLERANCE:
                self._refuse(
                    Count.ODOM_CLOCK, f"stamped {off:+.1f} s from this host's clock "
                    f"(at most {ODOM_CLOCK_TOLERANCE} s): a replay, or clocks not synchronized",
                )  # fmt: skip
                continue
            if self.stamp is not None and self.stamp - self.wall() > ODOM_CLOCK_TOLERANCE:
                self.stamp = None  # the clocks were set back: the last stamp is no measure
            if self.stamp is not None and stamp <= self.stamp:
                self._refuse(
                    Count.ODOM_NOT_NEWER, f"stamped {stamp - self.stamp:+.3f} s after the last"
                )
                continue
            p, v = sample.pose.pose, sample.twist.twist
            try:
                pose = conv.pose_from_odometry(
                    (p.position.x, p.position.y, p.position.z),
                    (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w),
                    (v.linear.x, v.linear.y, v.linear.z),
                    (v.angular.x, v.angular.y, v.angular.z),
                )
            except conv.OdometryError as error:
                self._refuse(Count.ODOM_MALFORMED, str(error))
                continue
            if self.frames is None:
                self.frames = frames
                log.info("odometry taken in frames %r -> %r", *frames)
            self.counters[Count.ODOM_RECEIVED] += 1
            self.pose, self.stamp = pose, stamp
            self.received_at = self.clock()
        return self.pose


class AgentLoopStopped(RuntimeError):
    """The joined agent's loop died (its exception is in the log): the bridge stops, ROS
    told to hold."""


class RunStateToRos:
    """A joined platform's hold and run mode on ROS 2 (``/fedlab/LAB/NAME/hold`` and
    ``/run``): :meth:`publish` at each control step writes what changed, and each again
    every second; :meth:`close` writes ``hold`` true last."""

    def __init__(
        self,
        participant: DomainParticipant,
        agent: AgentId,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.clock = clock
        hold = Topic(participant, conv.dds_topic(conv.agent_topic(agent, "hold")), Bool)
        run = Topic(participant, conv.dds_topic(conv.agent_topic(agent, "run")), String)
        self._hold = DataWriter(participant, hold, state_writer_qos(BOOL))
        self._run = DataWriter(participant, run, state_writer_qos(STRING_MESSAGE))
        self._hold_news, self._run_news = conv.Repeated(), conv.Repeated()
        self.counters: Counter[Count] = Counter()
        self._lock = threading.Lock()
        self._closed = False

    def publish(self, mode: str, hold: str | None) -> None:
        """Write the hold (:func:`~federation.bridge.ros2_core.must_hold`) and ``mode``
        if changed or due again; nothing once closed."""
        now = self.clock()
        hold_it = conv.must_hold(mode, hold)
        with self._lock:
            if self._closed:
                return
            if self._hold_news.due(hold_it, now):
                self._hold.write(Bool(hold_it))
                self.counters[Count.ROS_HOLD_WRITTEN] += 1
            if self._run_news.due(mode, now):
                self._run.write(String(mode))

    def close(self) -> None:
        """The bridge stops: hold, for whoever still listens, and the last word (a step
        of the agent's loop still under way writes nothing after it)."""
        with self._lock:
            self._closed = True
            self._hold.write(Bool(True))


class Ros2Agent(AgentRuntime):
    """An agent whose pose is a ROS 2 platform's odometry (:class:`OdometryPlatform`).

    Holds (``hold: "source_stale"``) and publishes no pose while the odometry is stale; tells
    ROS whether the platform may move (``state``, :class:`RunStateToRos`)."""

    platform: OdometryPlatform

    def __init__(self, config: AgentConfig, session: zenoh.Session, platform: OdometryPlatform,
                 odom_topic: str, state: RunStateToRos | None = None):  # fmt: skip
        super().__init__(config, session, platform=platform)
        self.odom_topic = odom_topic
        self.state = state

    def control_step(self) -> None:
        super().control_step()
        stale = self.platform.stale
        if stale and not self.safety.holds(Hold.SOURCE_STALE):
            self.safety.apply(Trigger.SOURCE_STALE)  # held and said at once
            self.count(Count.ODOM_STALE_HOLDS)
            why = self.platform.last_rejection
            log.warning(
                "no valid odometry on %s for %.1f s%s: hold", self.odom_topic,
                self.platform.timeout, "" if why is None else f" (last refused: {why})",
            )  # fmt: skip
        elif not stale and self.safety.holds(Hold.SOURCE_STALE):
            self.safety.apply(Trigger.SOURCE_FRESH)  # held still if its run has not begun
            log.info("odometry on %s flows again: %s", self.odom_topic, self.hold or "released")
        if self.state is not None:
            # Whatever holds it, said or not yet: the supervisor's hold, the platform held
            # (an abort on Zenoh's thread), odometry gone stale since the check above.
            reason: str | None = self.hold
            if reason is None and (self.platform.held or self.platform.stale):
                reason = "held" if self.platform.held else Hold.SOURCE_STALE
            self.state.publish(self.run_state.mode, reason)

    def publish_pose(self) -> None:
        if self.platform.stale:
            self.count(Count.POSE_WITHHELD)  # fail closed: followers see the link go quiet
            return
        super().publish_pose()

    def counter_snapshot(self) -> dict[Count, int]:
        state = {} if self.state is None else dict(self.state.counters)
        return super().counter_snapshot() | dict(self.platform.counters) | state

    def status(self) -> Status:
        return super().status().model_copy(update={"platform": f"ros2:{self.odom_topic}"})


def run_ros2_bridge(
    session: zenoh.Session,
    stop: threading.Event,
    federation: str = keys.DEFAULT_FEDERATION,
    domain_id: int = 0,
    join: AgentConfig | None = None,
    odom_topic: str | None = None,
    odom_timeout: float = 0.5,
    duration_s: float | None = None,
) -> Counter[Count]:
    """Run the bridge until ``stop`` (or ``duration_s``); with ``join``, the ROS 2 platform
    reading ``odom_topic`` joins as that agent. Returns the forwarding counters."""
    participant = DomainParticipant(domain_id)
    forward = FederationToRos(session, participant, federation)
    agent: Ros2Agent | None = None
    thread: threading.Thread | None = None
    agent_stop = threading.Event()
    try:
        if join is not None:
            if odom_topic is None:
                raise ValueError("joining a ROS 2 platform needs its odometry topic (--odom)")
            topic = Topic(participant, conv.dds_topic(odom_topic), Odometry)
            reader = DataReader(participant, topic, odometry_reader_qos())
            platform = OdometryPlatform(reader, odom_timeout, rate=join.pose_rate)
            state = RunStateToRos(participant, join.agent)
            agent = Ros2Agent(join, session, platform, conv.ros_topic(odom_topic), state)
            agent.start()
            thread = threading.Thread(target=agent.run, args=(agent_stop,), name="ros2-agent")
            thread.start()
        forward.start()
        log.info(
            "bridge up: federation %s on ROS 2 domain %d%s", federation, domain_id,
            "" if join is None else f"; {join.agent} from {odom_topic}",
        )  # fmt: skip
        deadline = None if duration_s is None else time.monotonic() + duration_s
        last_note = time.monotonic()
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            if thread is not None and not thread.is_alive():
                # Its loop died (its exception is in the log): nothing tells ROS any more.
                raise AgentLoopStopped(f"{join.agent if join else 'the agent'}: its loop stopped")
            forward.step(0.05)
            if time.monotonic() - last_note >= 10.0:
                last_note = time.monotonic()
                log.info("forwarded: %s", {k.value: v for k, v in forward.counters.items()})
        return forward.counters
    finally:
        if agent is not None and agent.state is not None:
            try:  # first: ROS hears hold before anything here can wait or fail
                agent.state.close()
            except Exception:
                log.exception("hold not written to ROS")
        agent_stop.set()
        if thread is not None:
            thread.join(10)
        forward.close()
        if agent is not None:
            agent.close()

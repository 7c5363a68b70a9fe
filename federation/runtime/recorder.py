"""Recording an agent's run to an MCAP file (Foxglove opens it).

Every message is JSON on one of the channels of :mod:`federation.core.channels`
(:class:`~federation.core.channels.Channel`, where their fields are listed); each
carries ``t_exec`` (the agent's clock) and ``host_monotonic`` (the host's clock
read at the same instant), so recordings of agents on one machine line up exactly.
Their JSON schemas type every field, so Foxglove plots them without setup; and each
pose sent is also written in Foxglove's own types (``/tf``: ``foxglove.FrameTransforms``,
``fedlab_common`` -> ``LAB/NAME``; ``/pose``: ``foxglove.PoseInFrame``; protobuf, the
Foxglove SDK's schemas), so Foxglove's 3D panel shows the platform as soon as a
recording is opened. :func:`read_messages` reads the JSON channels, old and new files.

Recording never blocks the agent and wakes no thread: :meth:`Recorder.record`
appends the message to a bounded buffer (dropping and counting when full), and
one writer thread per process encodes and writes what has gathered in every open
recorder every ``FLUSH_PERIOD`` seconds. Waking a writer per message cost each
callback an interpreter-lock handover (most of the pose latency's tail), and a
writer per recorder meant 16 more threads waking in a process of 16 agents.
"""

from __future__ import annotations

import ctypes
import json
import logging
import math
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)
from foxglove.messages import Pose as FoxglovePose
from mcap.reader import make_reader
from mcap.writer import Writer

from federation.core.channels import (
    CHANNEL_FIELDS,
    COMMON_FRAME,
    FOXGLOVE_CHANNELS,
    Channel,
    json_schema,
)

__all__ = [
    "WRITER_THREAD",
    "Message",
    "Recorder",
    "Shared",
    "name_os_thread",
    "read_messages",
    "read_metadata",
]

log = logging.getLogger("fedlab.recorder")

CHUNK_SIZE = 64 * 1024
"""Bytes of messages gathered (uncompressed) before they are compressed and written as
one chunk. An agent killed mid-run loses at most the last chunk, and each recorder
holds one in memory with its index: a follower's 5 to 6 kB a second fill 64 kB in about
12 s (256 kB took 47 s: 32 followers' chunks came to about 13 MiB a worker, likely
part of the 60 to 80 MiB a 256-agent federation's workers grew by: issue 17)."""

# s between writes of the buffered messages: at 20 Hz, 16 co-hosted agents' recorders
# cost their process 6 ms a second of flush calls; at 10 Hz a write still holds the
# interpreter for well under a millisecond (issue 17).
FLUSH_PERIOD = 0.1
_TF, _POSE = FOXGLOVE_CHANNELS  # "/tf", "/pose": Foxglove's types, from /pose/sent


class Shared:
    """A message that several recorders queue (a pose that every follower on a feed
    records: :mod:`federation.runtime.links`): encoded to JSON once, by the first
    write, not once per recorder (issue 17: a lean agent). Its dict must not change
    once queued. Not for ``/pose/sent``, whose dicts are also written in Foxglove's
    types (each agent records its own pose: nothing to share)."""

    __slots__ = ("_data", "message")

    def __init__(self, message: dict[str, Any]):
        self.message = message
        self._data: bytes | None = None

    def data(self) -> bytes:
        """The message's JSON (two writers racing both encode it: the same bytes)."""
        data = self._data
        if data is None:
            data = self._data = json.dumps(self.message).encode()
        return data


Message = dict[str, Any] | bytes | Shared
"""What a recorder takes: a dict, its JSON already encoded, or one shared by several."""


class Recorder:
    """One agent's MCAP file; ``channels``: the ones recorded (default: all), at most
    ``capacity`` messages buffered."""

    def __init__(
        self,
        path: str | Path,
        agent: str,
        channels: list[Channel] | list[str] | None = None,
        capacity: int = 200_000,
    ):
        unknown = set(channels or ()) - set(Channel)
        if unknown:
            choices = [str(c) for c in Channel]
            raise ValueError(f"unknown channels {sorted(unknown)}: choose from {choices}")
        self.channels: set[str] = {str(c) for c in channels or Channel}
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dropped = 0
        self.written = 0
        self.unwritable = 0  # messages that could not be encoded, left out
        self.capacity = capacity
        self._pending: deque[tuple[str, int, Message]] = deque()
        self._write_lock = threading.Lock()  # the writer thread or close(), not both
        self._closed = False
        self._file = self.path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE)
        self._writer.start(profile="", library="fedlab")
        self._channels: dict[str, int] = {}
        for channel in CHANNEL_FIELDS:
            topic = str(channel)
            schema_id = self._writer.register_schema(
                name=topic.strip("/").replace("/", "."),
                encoding="jsonschema",
                data=json.dumps(json_schema(channel)).encode(),
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id, metadata={"agent": agent}
            )
        # Foxglove's types beside them: the platform in Foxglove's 3D panel without setup.
        self.frame = agent
        self._foxglove = Channel.POSE_SENT in self.channels
        if self._foxglove:
            for topic, kind in ((_TF, FrameTransforms), (_POSE, PoseInFrame)):
                schema = kind.get_schema()
                schema_id = self._writer.register_schema(
                    name=schema.name, encoding=schema.encoding, data=schema.data
                )
                self._channels[topic] = self._writer.register_channel(
                    topic=topic, message_encoding=schema.encoding, schema_id=schema_id,
                    metadata={"agent": agent},
                )  # fmt: skip
        _WRITER.add(self)

    def record(self, topic: str, message: Message) -> None:
        """Buffer one message (a dict, its JSON already encoded, or a :class:`Shared`);
        never blocks (a full buffer drops and counts it)."""
        if topic not in self.channels:
            return
        if len(self._pending) >= self.capacity:
            self.dropped += 1
            return
        self._pending.append((topic, time.time_ns(), message))  # atomic: no lock, no wakeup

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record in the file (a run's id, versions, configuration...)."""
        with self._write_lock:
            if not self._closed:
                self._writer.add_metadata(name, data)

    def flush(self) -> None:
        """Encode and write the buffered messages (the writer thread calls it)."""
        if not self._pending:
            return  # nothing gathered: no lock taken
        with self._write_lock:
            if not self._closed:
                self._write_pending()

    def _write_pending(self) -> None:
        pending, channels, add = self._pending, self._channels, self._writer.add_message
        while pending:
            topic, stamp, message = pending.popleft()
            try:
                if isinstance(message, bytes):
                    data = message
                elif isinstance(message, Shared):
                    data = message.data()
                else:
                    data = json.dumps(message).encode()
            except (TypeError, ValueError):  # not JSON (an object, a circular dict): left out
                self.unwritable += 1
                continue
            add(channels[topic], stamp, data, stamp)
            self.written += 1
            if isinstance(message, dict) and topic == Channel.POSE_SENT and self._foxglove:
                self._write_foxglove(stamp, message)
        self._file.flush()  # the chunks written reach the file: a kill loses only the last

    def _write_foxglove(self, stamp: int, message: dict[str, Any]) -> None:
        """The pose sent as Foxglove's transform and pose in frame, stamped as logged."""
        try:
            x, y, heading = float(message["x"]), float(message["y"]), float(message["heading"])
        except (KeyError, TypeError, ValueError):
            return  # not a pose: nothing to show
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(heading)):
            return
        when = Timestamp(stamp // 1_000_000_000, stamp % 1_000_000_000)
        where = Vector3(x=x, y=y, z=0.0)
        turn = Quaternion(x=0.0, y=0.0, z=math.sin(heading / 2), w=math.cos(heading / 2))
        tf = FrameTransform(
            timestamp=when, parent_frame_id=COMMON_FRAME, child_frame_id=self.frame,
            translation=where, rotation=turn,
        )  # fmt: skip
        pose = PoseInFrame(
            timestamp=when, frame_id=COMMON_FRAME,
            pose=FoxglovePose(position=where, orientation=turn),
        )  # fmt: skip
        add, channels = self._writer.add_message, self._channels
        add(channels[_TF], stamp, FrameTransforms(transforms=[tf]).encode(), stamp)
        add(channels[_POSE], stamp, pose.encode(), stamp)

    def close(self) -> None:
        """Write what is buffered, then finish the file (summary and index)."""
        _WRITER.remove(self)
        with self._write_lock:
            if self._closed:
                return
            self._closed = True
            try:
                try:
                    self._write_pending()
                finally:  # whatever the last messages were, the file is finished
                    self._writer.finish()  # type: ignore[no-untyped-call]
            finally:
                self._file.close()
        if self.dropped:
            log.warning("recorder dropped %d messages (queue full)", self.dropped)
        if self.unwritable:
            log.warning("recorder left out %d messages that were not JSON", self.unwritable)


class _WriterThread:
    """The process's one writer: flushes every open recorder each ``FLUSH_PERIOD``;
    started by the first recorder, gone once none is open."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._recorders: set[Recorder] = set()
        self._running = False

    def add(self, recorder: Recorder) -> None:
        with self._lock:
            self._recorders.add(recorder)
            if not self._running:
                self._running = True
                threading.Thread(target=self._run, name="recorder", daemon=True).start()

    def remove(self, recorder: Recorder) -> None:
        with self._lock:
            self._recorders.discard(recorder)

    def _run(self) -> None:
        name_os_thread(WRITER_THREAD)
        while True:
            time.sleep(FLUSH_PERIOD)
            with self._lock:
                recorders = list(self._recorders)
                if not recorders:
                    self._running = False
                    return
            for recorder in recorders:
                try:
                    recorder.flush()
                except Exception:  # a full disk: keep writing the others
                    log.exception("writing %s failed", recorder.path)


_WRITER = _WriterThread()
WRITER_THREAD = "fedlab-recorder"
"""The writer thread's name as the OS shows it (``top -H``, ``/proc/PID/task/*/comm``):
``fedlab bench scale`` reports its CPU apart from the agents' loop."""


def name_os_thread(name: str) -> None:
    """Name the calling thread for the OS (Linux ``prctl(PR_SET_NAME)``, 15 bytes at
    most; before Python 3.14 a Python thread carries the interpreter's name). Nothing
    where the call is not available."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(15, name.encode()[:15], 0, 0, 0)  # 15: PR_SET_NAME
    except (OSError, AttributeError):
        pass


def read_messages(
    path: str | Path, topics: list[str] | None = None
) -> dict[str, list[dict[str, Any]]]:
    """Every JSON message of a recording by channel, in log-time order (the channels in
    Foxglove's types, ``/tf`` and ``/pose``, repeat ``/pose/sent`` and are left out)."""
    out: dict[str, list[dict[str, Any]]] = {str(t): [] for t in (topics or Channel)}
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            if channel.message_encoding != "json":  # Foxglove's types: for Foxglove
                continue
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """A recording's metadata records by name (empty for a file without them)."""
    with Path(path).open("rb") as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}

"""Recording an agent's run to an MCAP file (Foxglove opens it).

Every message is JSON on one of the channels of :mod:`federation.core.channels`
(:class:`~federation.core.channels.Channel`, where their fields are listed); each
carries ``t_exec`` (the agent's clock) and ``host_monotonic`` (the host's clock
read at the same instant), so recordings of agents on one machine line up exactly.
Their JSON schemas type every field, so Foxglove plots them without setup; and each
pose sent is also written in Foxglove's own types (``/tf``: ``foxglove.FrameTransforms``,
``fedlab_common`` -> ``LAB/NAME``; ``/pose``: ``foxglove.PoseInFrame``; protobuf, the
Foxglove SDK's schemas), so Foxglove's 3D panel shows the platform as soon as a
recording is opened. Reading, checking and salvaging the files is
:mod:`federation.runtime.mcapfile`'s (its names are importable from here too).

Recording never blocks the agent and wakes no thread: :meth:`Recorder.record`
appends the message to a bounded buffer (dropping and counting when full), and
one writer thread per process encodes and writes what has gathered in every open
recorder every ``FLUSH_PERIOD`` seconds. Waking a writer per message would cost each
callback an interpreter-lock handover (most of the pose latency's tail), and a
writer per recorder would wake 16 more threads in a process of 16 agents.

A recorder given ``max_bytes`` stops there: a peer publishing far too fast (a bug, an
insider) fills no disk. Messages past it are dropped and counted, one warning is
logged and one ``recording_truncated`` event written on ``/control``; the file is
still finished, and its ``fedlab.recording`` metadata record (written at close, in
every file) says how many messages it holds and what was left out. The agent's own
``/control`` events and ``/status`` lines (a few a second) still take up to
``RESERVE_BYTES`` more: ``fedlab report`` finds a run's start in its control events
and an agent's role and peers in its last status. A write that failed (a full disk)
is counted too: such a file is not ``complete`` either.

An open recorder holds an advisory lock on its file (``flock``; gone with its process):
:func:`~federation.runtime.mcapfile.salvage`'s caller leaves a file that is still
being written alone, and one whose lock cannot be told (:func:`hold`).
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import json
import logging
import math
import os
import threading
import time
from collections import deque
from pathlib import Path
from typing import IO, Any

from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)
from foxglove.messages import Pose as FoxglovePose
from mcap.writer import Writer

from federation.core.channels import (
    CHANNEL_FIELDS,
    COMMON_FRAME,
    FOXGLOVE_CHANNELS,
    Channel,
    json_schema,
)
from federation.runtime.mcapfile import (
    CHUNK_SIZE,
    RECORDING_METADATA,
    RECOVERY_METADATA,
    Salvage,
    as_metadata,
    from_metadata,
    is_finished,
    read_messages,
    read_metadata,
    salvage,
)

__all__ = [
    "CHUNK_SIZE",
    "RECORDING_METADATA",
    "RECOVERY_METADATA",
    "RESERVE_BYTES",
    "WRITER_THREAD",
    "Message",
    "Recorder",
    "Salvage",
    "Shared",
    "as_metadata",
    "from_metadata",
    "hold",
    "is_finished",
    "name_os_thread",
    "read_messages",
    "read_metadata",
    "salvage",
]

log = logging.getLogger("fedlab.recorder")

# s between writes of the buffered messages: at 20 Hz, 16 co-hosted agents' recorders
# cost their process 6 ms a second of flush calls; at 10 Hz a write still holds the
# interpreter for well under a millisecond.
FLUSH_PERIOD = 0.1
_TF, _POSE = FOXGLOVE_CHANNELS  # "/tf", "/pose": Foxglove's types, from /pose/sent
# Bytes a message adds to the file beside its data: its record's header (31) and its
# entry in the chunk's message index (16).
_MESSAGE_OVERHEAD = 47
# Bytes the chunk being gathered may still add to the file (it is not there yet): at
# most CHUNK_SIZE of records before compression, their index entries, its header.
_CHUNK_BOUND = 2 * CHUNK_SIZE
RESERVE_BYTES = 1 << 20
"""Bytes a truncated recording still takes, past its limit, for the agent's own
``/control`` events and ``/status`` lines (the truncation event included): a run's
start, end and last status stay in the file. Half of it for status lines as they
come; past that only the latest is kept, written at close. A quarter at most for the
``/control`` events other than a run's end (``done``, ``aborted``), and an eighth at
most for the commands received and those ignored (any lab's operator may send
them): a flood of them leaves room for the agent's own events, and those for the
run's end."""
_RUN_ENDS = frozenset({"done", "aborted"})
_RECEIVED = frozenset({"command", "ignored"})
_RESERVED = frozenset({str(Channel.CONTROL), str(Channel.STATUS)})
_RESERVE_QUEUE = 1000  # messages of those channels buffered once truncated


class Shared:
    """A message that several recorders queue (a pose that every follower on a feed
    records: :mod:`federation.runtime.links`): encoded to JSON once, by the first
    write, not once per recorder (so that an agent stays lean). Its dict must not change
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
    ``capacity`` messages buffered, at most ``max_bytes`` written (None: no limit)."""

    def __init__(
        self,
        path: str | Path,
        agent: str,
        channels: list[Channel] | list[str] | None = None,
        capacity: int = 200_000,
        max_bytes: int | None = None,
    ):
        unknown = set(channels or ()) - set(Channel)
        if unknown:
            choices = [str(c) for c in Channel]
            raise ValueError(f"unknown channels {sorted(unknown)}: choose from {choices}")
        self.channels: set[str] = {str(c) for c in channels or Channel}
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dropped = 0  # the buffer was full
        self.written = 0
        self.unwritable = 0  # messages that could not be encoded, left out
        self.capacity = capacity
        self.max_bytes = max_bytes
        self.truncated = False  # max_bytes reached: every later message dropped
        self.over_budget = 0  # messages dropped because of it
        self.reserve_used = 0  # bytes past it: /control and /status (RESERVE_BYTES)
        self.reserve_events = 0  # of which /control but a run's end (a quarter at most)
        self.reserve_received = 0  # of which commands received or ignored (an eighth)
        self.write_errors = 0  # writes that failed (a full disk): messages lost
        self._held_status: tuple[int, bytes, int] | None = None  # past half the reserve
        self._pending: deque[tuple[str, int, Message]] = deque()
        self._write_lock = threading.Lock()  # the writer thread or close(), not both
        self._closed = False
        self._file = self.path.open("wb")
        if hold(self._file) is False:
            log.warning("%s is locked by another process: two recorders write it", self.path)
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
        # An upper bound of the file's size once what was added is written: refreshed
        # from the file's position only when it reaches max_bytes (see _refit).
        self._bound = self._file.tell() + _CHUNK_BOUND
        _WRITER.add(self)

    def record(self, topic: str, message: Message) -> None:
        """Buffer one message (a dict, its JSON already encoded, or a :class:`Shared`);
        never blocks (a full buffer drops and counts it)."""
        if topic not in self.channels:
            return
        if len(self._pending) >= self.capacity:  # 0 once truncated: dropped here, cheaply
            if self.truncated:
                if topic in _RESERVED and len(self._pending) < _RESERVE_QUEUE:
                    self._pending.append((topic, time.time_ns(), message))  # the reserve's
                    return
                self.over_budget += 1
            else:
                self.dropped += 1
            return
        self._pending.append((topic, time.time_ns(), message))  # atomic: no lock, no wakeup

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record in the file (a run's id, versions, configuration...)."""
        with self._write_lock:
            if not self._closed:
                self._writer.add_metadata(name, data)
                self._file.flush()  # on disk now: a recording killed early still says whose
                self._bound = self._file.tell() + _CHUNK_BOUND

    def flush(self) -> None:
        """Encode and write the buffered messages (the writer thread calls it). A write
        that fails is counted (``write_errors``: the file is no longer complete) and
        raised."""
        if not self._pending:
            return  # nothing gathered: no lock taken
        with self._write_lock:
            if not self._closed:
                try:
                    self._write_pending()
                except Exception:
                    self.write_errors += 1
                    raise

    def _write_pending(self) -> None:
        pending, channels, add = self._pending, self._channels, self._writer.add_message
        limit = self.max_bytes
        while pending:
            topic, stamp, message = pending.popleft()
            if self.truncated and topic not in _RESERVED:  # queued before: dropped all the same
                self.over_budget += 1
                continue
            data = self._encode(message)
            if data is None:
                continue
            shown = None
            if isinstance(message, dict) and topic == Channel.POSE_SENT and self._foxglove:
                shown = self._foxglove_pair(stamp, message)
            if limit is not None and not self._admit(topic, stamp, message, data, shown, limit):
                continue
            add(channels[topic], stamp, data, stamp)
            self.written += 1
            if shown is not None:
                add(channels[_TF], stamp, shown[0], stamp)
                add(channels[_POSE], stamp, shown[1], stamp)
        self._file.flush()  # the chunks written reach the file: a kill loses only the last

    def _encode(self, message: Message) -> bytes | None:
        """The message's JSON; None (counted) for one that is not JSON (an object, a
        circular dict): it is left out."""
        try:
            if isinstance(message, bytes):
                return message
            if isinstance(message, Shared):
                return message.data()
            return json.dumps(message).encode()
        except (TypeError, ValueError):
            self.unwritable += 1
            return None

    def _admit(
        self,
        topic: str,
        stamp: int,
        message: Message,
        data: bytes,
        shown: tuple[bytes, bytes] | None,
        limit: int,
    ) -> bool:
        """Whether a message (``data``, and ``shown`` in Foxglove's types) is written
        within ``limit`` (``max_bytes``): the file truncated when it would pass it; past
        it, only ``/control`` and ``/status`` messages, in the reserve
        (:meth:`_in_reserve`)."""
        size = len(data) + _MESSAGE_OVERHEAD
        if shown is not None:
            size += len(shown[0]) + len(shown[1]) + 2 * _MESSAGE_OVERHEAD
        if not self.truncated:
            self._bound += size
            if self._bound > limit and not self._refit(size, limit):
                self._truncate(stamp)
        if not self.truncated:
            return True
        if topic not in _RESERVED:  # now or before: only /control and /status
            self.over_budget += 1
            return False
        event = message.get("event") if isinstance(message, dict) else None
        other = topic == Channel.CONTROL and event not in _RUN_ENDS
        received = other and event in _RECEIVED
        return self._in_reserve(topic, stamp, data, size, other, received)

    def _refit(self, size: int, limit: int) -> bool:
        """Whether a message of ``size`` bytes keeps the file within ``limit`` after all,
        its upper bound (``_bound``: each message's bytes before compression added to it)
        having reached the limit: the bound taken again from the file's position (a system
        call, not made for every message), plus what the chunk being gathered may add."""
        self._bound = self._file.tell() + _CHUNK_BOUND + size
        return self._bound <= limit

    def _in_reserve(
        self,
        topic: str,
        stamp: int,
        data: bytes,
        size: int,
        other: bool = False,
        received: bool = False,
    ) -> bool:
        """Whether a ``/control`` or ``/status`` message past the limit is written now,
        taking ``size`` bytes of the reserve: a run's end while the reserve lasts, an
        ``other`` control event while its quarter does (a ``received`` command or one
        ignored while its eighth does); a status line while half of it does, else kept
        (the latest only) for close. The others are dropped and counted."""
        if received and self.reserve_received + size > RESERVE_BYTES // 8:
            self.over_budget += 1
            return False
        if other and self.reserve_events + size > RESERVE_BYTES // 4:
            self.over_budget += 1
            return False
        if topic == Channel.STATUS and self.reserve_used + size > RESERVE_BYTES // 2:
            if self._held_status is not None:
                self.over_budget += 1  # a later one replaces it
            self._held_status = (stamp, data, size)
            return False
        if self.reserve_used + size > RESERVE_BYTES:
            self.over_budget += 1
            return False
        self.reserve_used += size
        if other:
            self.reserve_events += size
        if received:
            self.reserve_received += size
        return True

    def _write_held_status(self) -> None:
        """At close: the last status line past half the reserve, if the reserve holds it."""
        held, self._held_status = self._held_status, None
        if held is None:
            return
        stamp, data, size = held
        if self.reserve_used + size > RESERVE_BYTES:
            self.over_budget += 1
            return
        self.reserve_used += size
        self._writer.add_message(self._channels[Channel.STATUS], stamp, data, stamp)
        self.written += 1

    def _truncate(self, stamp: int) -> None:
        """The budget is reached: drop every later message (``record`` at once) but the
        reserve's, say so once in the log and once in the file (a ``/control`` event,
        past the budget, in the reserve)."""
        self.truncated = True
        self.capacity = 0
        detail = (
            f"recording reached its limit of {self.max_bytes} bytes: later messages dropped "
            "(record_max_mb)"
        )
        log.warning("%s: %s", self.path, detail)
        event = {
            "event": "recording_truncated", "command": None, "at": None, "t_sim": None,
            "host_monotonic": time.monotonic(), "detail": detail,
        }  # fmt: skip
        data = json.dumps(event).encode()
        self.reserve_used += len(data) + _MESSAGE_OVERHEAD
        self._writer.add_message(self._channels[Channel.CONTROL], stamp, data, stamp)

    def report(self) -> dict[str, Any]:
        """What the file holds and what it left out, as JSON-ready data."""
        return {
            "messages": self.written,
            "complete": self.complete,
            "truncated": self.truncated,
            "max_bytes": self.max_bytes,
            "dropped_over_budget": self.over_budget,
            "dropped_queue_full": self.dropped,
            "unwritable": self.unwritable,
            "write_errors": self.write_errors,
            "reserve_bytes": self.reserve_used,
        }

    @property
    def complete(self) -> bool:
        """Every message given was written: none dropped, none left out, no write failed."""
        return not (
            self.truncated or self.over_budget or self.dropped or self.unwritable
            or self.write_errors
        )  # fmt: skip

    def _foxglove_pair(self, stamp: int, message: dict[str, Any]) -> tuple[bytes, bytes] | None:
        """The pose sent as Foxglove's transform and pose in frame (encoded), stamped as
        logged; None for what is not a finite pose."""
        try:
            x, y, heading = float(message["x"]), float(message["y"]), float(message["heading"])
        except (KeyError, TypeError, ValueError):
            return None  # not a pose: nothing to show
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(heading)):
            return None
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
        return FrameTransforms(transforms=[tf]).encode(), pose.encode()

    def _sync(self) -> None:
        """The file on disk; a failure (EIO) counts as a failed write: the recording is
        then not complete, and its run says so. A file that cannot be synced (a pipe,
        /dev/null: EINVAL) has nothing to lose."""
        try:
            os.fsync(self._file.fileno())
        except OSError as error:
            if error.errno != errno.EINVAL:
                self.write_errors += 1
                log.error("%s: not on disk: %s", self.path, error)

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
                    self._write_held_status()
                except Exception:
                    self.write_errors += 1  # said in the metadata record below
                    raise
                finally:  # whatever the last messages were, the file is finished
                    self._writer.add_metadata(RECORDING_METADATA, as_metadata(self.report()))
                    self._writer.finish()  # type: ignore[no-untyped-call]
                    # On disk before anyone (a run's manifest, collect) takes it as
                    # finished: after a power cut, a finished file is a whole one.
                    self._file.flush()
                    self._sync()
            finally:
                self._file.close()
        if self.dropped:
            log.warning("recorder dropped %d messages (queue full)", self.dropped)
        if self.unwritable:
            log.warning("recorder left out %d messages that were not JSON", self.unwritable)
        if self.over_budget:
            log.warning(
                "%s: %d messages dropped past its limit of %s bytes",
                self.path, self.over_budget, self.max_bytes,
            )  # fmt: skip
        if self.write_errors:
            log.warning("%s: %d writes failed: messages lost", self.path, self.write_errors)


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
                except Exception:  # a full disk: keep writing the others (counted: flush)
                    if recorder.write_errors == 1:
                        log.exception("writing %s failed", recorder.path)
                    else:  # every period while the disk is full: not a traceback each time
                        log.debug("writing %s failed again", recorder.path, exc_info=True)


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


_lock_unknown_said = False  # hold() could not tell once: logged, not at every file


def hold(file: IO[bytes]) -> bool | None:
    """Take the advisory lock of an open file (``flock``, exclusive, without waiting):
    True once taken (released when the file is closed or its process dies, killed or
    not); False if another open file holds it (a process writing it, this one
    included); None if it cannot be told (the filesystem refused: ``ENOLCK`` where it
    keeps no locks, ``EBADF`` where NFS emulates ``flock`` with a write lock and the
    file is open read-only, anything else), logged once a process. Open the file
    ``r+b`` (or for writing) to ask: a file that cannot be told must be left alone."""
    global _lock_unknown_said
    try:
        fcntl.flock(file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as error:
        if not _lock_unknown_said:
            _lock_unknown_said = True
            name = errno.errorcode.get(error.errno or 0, str(error.errno))
            log.warning(
                "%s: whether another process writes it cannot be told (flock: %s, %s): "
                "such recordings are left alone (said once)",
                getattr(file, "name", "a file"), name, error.strerror,
            )  # fmt: skip
        return None
    return True

"""Recording an agent's run to an MCAP file (Foxglove opens it).

Every message is JSON on one of the channels of :mod:`federation.core.channels`
(:class:`~federation.core.channels.Channel`, where their fields are listed); each
carries ``t_exec`` (the agent's clock) and ``host_monotonic`` (the host's clock
read at the same instant), so recordings of agents on one machine line up exactly.

Recording never blocks the agent and wakes no thread: :meth:`Recorder.record`
appends the message to a bounded buffer (dropping and counting when full), and
one writer thread per process encodes and writes what has gathered in every open
recorder every ``FLUSH_PERIOD`` seconds. Waking a writer per message cost each
callback an interpreter-lock handover (most of the pose latency's tail), and a
writer per recorder meant 16 more threads waking in a process of 16 agents.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import Writer

from federation.core.channels import CHANNEL_FIELDS, Channel

__all__ = ["Recorder", "read_messages"]

log = logging.getLogger("fedlab.recorder")

FLUSH_PERIOD = 0.05  # s between writes of the buffered messages


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
        self.capacity = capacity
        self._pending: deque[tuple[str, int, dict[str, Any]]] = deque()
        self._write_lock = threading.Lock()  # the writer thread or close(), not both
        self._closed = False
        self._file = self.path.open("wb")
        # Small chunks: an agent killed mid-run loses at most the last chunk.
        self._writer = Writer(self._file, chunk_size=256 * 1024)
        self._writer.start(profile="", library="fedlab")
        self._channels: dict[str, int] = {}
        for channel, fields in CHANNEL_FIELDS.items():
            topic = str(channel)
            schema = {
                "title": topic,
                "type": "object",
                "properties": {name: {} for name in fields},
            }
            schema_id = self._writer.register_schema(
                name=topic.strip("/").replace("/", "."),
                encoding="jsonschema",
                data=json.dumps(schema).encode(),
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id, metadata={"agent": agent}
            )
        _WRITER.add(self)

    def record(self, topic: str, message: dict[str, Any]) -> None:
        """Buffer one message; never blocks (a full buffer drops and counts it)."""
        if topic not in self.channels:
            return
        if len(self._pending) >= self.capacity:
            self.dropped += 1
            return
        self._pending.append((topic, time.time_ns(), message))  # atomic: no lock, no wakeup

    def flush(self) -> None:
        """Encode and write the buffered messages (the writer thread calls it)."""
        with self._write_lock:
            if not self._closed:
                self._write_pending()

    def _write_pending(self) -> None:
        pending, channels, add = self._pending, self._channels, self._writer.add_message
        while pending:
            topic, stamp, message = pending.popleft()
            add(channels[topic], stamp, json.dumps(message).encode(), stamp)
            self.written += 1

    def close(self) -> None:
        """Write what is buffered, then finish the file (summary and index)."""
        _WRITER.remove(self)
        with self._write_lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._write_pending()
                self._writer.finish()  # type: ignore[no-untyped-call]
            finally:
                self._file.close()
        if self.dropped:
            log.warning("recorder dropped %d messages (queue full)", self.dropped)


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


def read_messages(
    path: str | Path, topics: list[str] | None = None
) -> dict[str, list[dict[str, Any]]]:
    """Every message of a recording by channel, in log-time order."""
    out: dict[str, list[dict[str, Any]]] = {str(t): [] for t in (topics or Channel)}
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out

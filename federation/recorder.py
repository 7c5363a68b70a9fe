"""Recording an agent's run to an MCAP file (Foxglove opens it).

Every message is JSON on one of these channels; each carries ``t_exec`` (the
agent's clock) and ``host_monotonic`` (the host's clock read at the same
instant), so recordings of agents on one machine line up exactly.

=====================  ============================================================
channel                message
=====================  ============================================================
``/pose/sent``         the pose published: t_exec, x, y, heading, vx, vy, omega
``/pose/received``     a pose received: agent, t (sender's clock), t_recv, pose
``/sync/exchange``     an accepted exchange: peer, t1, t2, t3, t2s, offset, delay,
                       estimate (the filtered offset after it)
``/reference``         guidance: t_sim, run_time, heading_ref, rate_ref, mode
``/truth``             a simulated platform's true pose (for evaluation)
``/control``           execution control: event, command, at, t_sim, mode
``/status``            the status message (as published)
=====================  ============================================================

Recording never blocks the agent and wakes no thread: :meth:`Recorder.record`
appends the message to a bounded buffer (dropping and counting when full) and a
writer thread encodes and writes what has gathered every ``flush_period``
seconds. Waking the writer per message cost each callback an interpreter-lock
handover; with 16 agents in a process that was most of the pose latency's tail.
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

__all__ = ["CHANNELS", "Recorder", "read_messages"]

log = logging.getLogger("fedlab.recorder")

_POSE = ["x", "y", "heading", "vx", "vy", "omega"]
CHANNELS: dict[str, list[str]] = {
    "/pose/sent": ["t_exec", "host_monotonic", *_POSE],
    "/pose/received": ["agent", "t", "t_recv", "host_monotonic", *_POSE],
    "/sync/exchange": [
        "peer", "t1", "t2", "t3", "t2s", "offset", "delay", "estimate", "host_monotonic",
    ],
    "/reference": [
        "t_exec", "host_monotonic", "t_sim", "run_time", "heading_ref", "rate_ref", "mode",
        "valves_open",
    ],
    "/truth": ["t_exec", "host_monotonic", *_POSE],
    "/control": ["event", "command", "at", "t_exec", "t_sim", "host_monotonic", "mode", "detail"],
    "/status": ["agent", "t_exec", "host_monotonic", "peers", "counters"],
}  # fmt: skip


class Recorder:
    def __init__(
        self,
        path: str | Path,
        agent: str,
        channels: list[str] | None = None,
        capacity: int = 200_000,
        flush_period: float = 0.05,
    ):
        unknown = set(channels or ()) - set(CHANNELS)
        if unknown:
            raise ValueError(f"unknown channels {sorted(unknown)}: choose from {list(CHANNELS)}")
        self.channels = set(channels or CHANNELS)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dropped = 0
        self.written = 0
        self.capacity = capacity
        self.flush_period = flush_period
        self._pending: deque[tuple[str, int, dict[str, Any]]] = deque()
        self._stop = threading.Event()
        self._file = self.path.open("wb")
        # Small chunks: an agent killed mid-run loses at most the last chunk.
        self._writer = Writer(self._file, chunk_size=256 * 1024)
        self._writer.start(profile="", library="fedlab")
        self._channels: dict[str, int] = {}
        for topic, fields in CHANNELS.items():
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
        self._thread = threading.Thread(target=self._drain, name="recorder", daemon=True)
        self._thread.start()

    def record(self, topic: str, message: dict[str, Any]) -> None:
        """Buffer one message; never blocks (a full buffer drops and counts it)."""
        if topic not in self.channels:
            return
        if len(self._pending) >= self.capacity:
            self.dropped += 1
            return
        self._pending.append((topic, time.time_ns(), message))  # atomic: no lock, no wakeup

    def _drain(self) -> None:
        while not self._stop.wait(self.flush_period):
            self._write_pending()
        self._write_pending()

    def _write_pending(self) -> None:
        pending, channels, add = self._pending, self._channels, self._writer.add_message
        while pending:
            topic, stamp, message = pending.popleft()
            add(channels[topic], stamp, json.dumps(message).encode(), stamp)
            self.written += 1

    def close(self) -> None:
        """Write what is buffered, then finish the file (summary and index)."""
        self._stop.set()
        self._thread.join(30)
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()
        if self.dropped:
            log.warning("recorder dropped %d messages (queue full)", self.dropped)


def read_messages(
    path: str | Path, topics: list[str] | None = None
) -> dict[str, list[dict[str, Any]]]:
    """Every message of a recording by channel, in log-time order."""
    out: dict[str, list[dict[str, Any]]] = {t: [] for t in (topics or CHANNELS)}
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out

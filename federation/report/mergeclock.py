"""Each agent's clock as its recording states it, for :mod:`federation.report.merge`'s
first pass: a streaming read of a recording's records (no chunk index loaded), the
offset estimate of its ``/reference`` thinned (:class:`Thinned`), its status lines'
bounds, wall and host times (:class:`AgentClock`, :func:`survey`), and the run's epoch
in UTC from the hosts' wall clocks (:func:`epoch`). Free of Zenoh; see
:mod:`federation.report.merge` for the mapping these feed.
"""

from __future__ import annotations

import io
import json
import math
import statistics
import struct
import tempfile
from array import array
from bisect import bisect_right
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel as McapChannel
from mcap.records import Chunk, Metadata, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import get_chunk_data_stream

from federation.core.channels import Channel
from federation.report.analysis import Clock
from federation.report.load import agent_from_filename, segment_of

__all__ = [
    "STAMP_FIELDS",
    "THIN_S",
    "AgentClock",
    "Epoch",
    "Thinned",
    "epoch",
    "number",
    "stream_messages",
    "survey",
]

STAMP_FIELDS: dict[str, str] = {
    Channel.POSE_SENT: "t_exec", Channel.POSE_RECEIVED: "t_recv",
    Channel.SYNC_EXCHANGE: "t3", Channel.REFERENCE: "t_exec", Channel.TRUTH: "t_exec",
    Channel.CONTROL: "t_exec", Channel.STATUS: "t_exec",
}  # fmt: skip
"""Each recorded channel's stamp on its agent's own clock (others: ``t_exec`` if there)."""
THIN_S = 0.5e-6  # s, half-width of the corridor the offset points are thinned within
_SURVEYED = [Channel.REFERENCE, Channel.STATUS, Channel.CONTROL, Channel.SYNC_EXCHANGE]


class _Series:
    """Rows of ``width`` numbers (float64) appended in order of their first, kept in an
    anonymous temporary file and read back a block of ``BLOCK`` rows at a time: the
    memory it holds is two blocks and one number per block, whatever its length.

    Block ``j`` is rows ``j * BLOCK`` to ``(j + 1) * BLOCK`` inclusive (one row shared
    with the next), so a value between two rows is always inside one block, and an
    interpolation or a search in it gives what one over every row would."""

    BLOCK = 4096

    def __init__(self, width: int):
        self.width = width
        self.n = 0
        self.firsts: list[float] = []  # the first number of each block's first row
        # Open as long as the series: close() closes it (deleted then).
        self._file = tempfile.TemporaryFile()  # noqa: SIM115
        self._buffer = array("d")  # rows appended, not yet in the file
        self._cache: dict[int, list[np.ndarray]] = {}  # the last two blocks read, by column
        # The last lookups' brackets: messages come in time order, most fall in the same.
        self._between = (math.inf, -math.inf, 0.0, 0.0)  # t0 <= t < t1: y0, y1
        self._near: tuple[float, float, int, list[float]] = (math.inf, -math.inf, -1, [])

    def __len__(self) -> int:
        return self.n

    def append(self, *row: float) -> None:
        if self.n % self.BLOCK == 0:
            self.firsts.append(row[0])
        self._buffer.extend(row)
        self.n += 1
        if len(self._buffer) >= self.BLOCK * self.width:
            self._flush()
        self._between = (math.inf, -math.inf, 0.0, 0.0)
        self._near = (math.inf, -math.inf, -1, [])

    def _flush(self) -> None:
        if self._buffer:
            self._file.seek(0, 2)
            self._file.write(self._buffer.tobytes())
            del self._buffer[:]

    def block(self, j: int) -> list[np.ndarray]:
        """Block ``j``'s columns (contiguous arrays)."""
        columns = self._cache.get(j)
        if columns is None:
            self._flush()
            lo, hi = j * self.BLOCK, min((j + 1) * self.BLOCK, self.n - 1)
            self._file.seek(lo * self.width * 8)
            rows = np.frombuffer(self._file.read((hi - lo + 1) * self.width * 8), dtype=float)
            table = rows.reshape(-1, self.width)
            columns = [np.ascontiguousarray(table[:, i]) for i in range(self.width)]
            if len(self._cache) >= 2:
                del self._cache[next(iter(self._cache))]
            self._cache[j] = columns
        return columns

    def _locate(self, t: float) -> int:
        return max(0, bisect_right(self.firsts, t) - 1)

    def interp(self, t: float) -> float:
        """The second number at ``t`` of the first, linear between rows, as
        :func:`numpy.interp` over every row gives it (the end rows' values outside
        them; the firsts strictly increasing). In the last bracket looked up it is
        numpy's formula, ``slope * (t - t0) + y0`` (``y0`` at ``t0``), without the lookup."""
        t0, t1, y0, y1 = self._between
        if t0 <= t < t1:  # numpy's: the row's value on it, else along the bracket
            return y0 if t == t0 else (y1 - y0) / (t1 - t0) * (t - t0) + y0
        columns = self.block(self._locate(t))
        x, y = columns[0], columns[1]
        k = int(np.searchsorted(x, t, side="right"))
        if 0 < k < len(x):
            self._between = (float(x[k - 1]), float(x[k]), float(y[k - 1]), float(y[k]))
        return float(np.interp(t, x, y))

    def near(self, t: float, column: int) -> list[float]:
        """``column`` of the rows ``k - 1`` and ``k`` that exist, ``k`` the number of rows
        whose first is ``t`` or less (:func:`bisect.bisect_right` over every row)."""
        low, high, kept, values = self._near
        if kept == column and low <= t < high:
            return values
        columns = self.block(self._locate(t))
        x = columns[0]
        k = int(np.searchsorted(x, t, side="right"))
        values = [float(columns[column][i]) for i in (k - 1, k) if 0 <= i < len(x)]
        low = float(x[k - 1]) if k > 0 else -math.inf
        high = float(x[k]) if k < len(x) else math.inf
        self._near = (low, high, column, values)
        return values

    def rows(self) -> Iterator[list[np.ndarray]]:
        """Every row once, as the columns of blocks in order."""
        for j in range(len(self.firsts)):
            columns = self.block(j)
            last = j == len(self.firsts) - 1
            yield columns if last else [c[:-1] for c in columns]

    def column(self, i: int) -> np.ndarray:
        """Column ``i`` of every row (loaded whole: for small series and tests)."""
        parts = [columns[i] for columns in self.rows()]
        return np.concatenate(parts) if parts else np.zeros(0)

    def close(self) -> None:
        self._file.close()
        self._cache.clear()


class Thinned:
    """Points ``(t, y)`` given in time order, kept only where needed: linear
    interpolation between kept points stays within ``2 * tolerance`` of every point
    given (the swinging door: a point is kept when no line from the last kept one
    passes within ``tolerance`` of all since). The kept points go to a temporary file
    (:class:`_Series`): it holds the last kept point and the corridor, nothing more."""

    def __init__(self, tolerance: float = THIN_S):
        self.tolerance = tolerance
        self.kept = _Series(2)
        self._anchor: tuple[float, float] | None = None  # the last point kept
        self._last: tuple[float, float] | None = None  # the last point given since
        self._low, self._high = -math.inf, math.inf
        self._done = False

    def __len__(self) -> int:
        return len(self.kept) + (self._last is not None and not self._done)

    def add(self, t: float, y: float) -> None:
        if self._anchor is None:
            self._anchor = (t, y)
            self.kept.append(t, y)
            return
        last = self._last
        if t <= (last[0] if last else self._anchor[0]):
            return  # not later than the last point: out of order, dropped
        low, high = self._corridor(t, y)
        if low > high and last is not None:  # no line fits them all: keep the last
            self._anchor = last
            self.kept.append(*last)
            self._low, self._high = -math.inf, math.inf
            low, high = self._corridor(t, y)
        self._low, self._high = low, high
        self._last = (t, y)

    def _corridor(self, t: float, y: float) -> tuple[float, float]:
        assert self._anchor is not None
        dt = t - self._anchor[0]
        low = (y - self.tolerance - self._anchor[1]) / dt
        high = (y + self.tolerance - self._anchor[1]) / dt
        return max(self._low, low), min(self._high, high)

    def finish(self) -> _Series:
        """The kept points and the last one given (no point may be added after)."""
        if not self._done and self._last is not None:
            self.kept.append(*self._last)
        self._done = True
        return self.kept

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """The kept points and the last one given, as arrays (loaded whole)."""
        kept = self.finish()
        return kept.column(0), kept.column(1)


def number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


_T, _BOUND, _WALL, _HOST = range(4)  # a status line's row: own clock, bound, log time, host


@dataclass
class AgentClock:
    """One agent's recording and how its clock maps to reference time."""

    agent: str
    path: Path
    segment: int = 1  # 1: the run's first recording; 2...: after each rejoin
    reference: str | None = None  # the reference agent its statuses name
    source: str = "none"  # "reference" (its own clock), "estimate" (/reference), "exchanges"
    estimate: _Series | None = None  # (own clock, reference minus own) points, s
    # Per status line: own clock, its reference_bound (NaN: none), its log time (host
    # wall clock) and host_monotonic (NaN: none), s.
    statuses: _Series = field(default_factory=lambda: _Series(4))
    bound_max: float | None = None  # the largest reference_bound a status line states
    started: float | None = None  # reference time of its started event
    first: float | None = None  # its first own-clock stamp surveyed
    host: str | None = None  # the host that recorded it (fedlab.run metadata)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    wall: Clock | None = None  # own clock = a + b * wall clock (s)
    wall_residual: float = 0.0  # s, largest distance of a status line from that line
    truth: Clock | None = None  # own clock = a + b * host monotonic (one host's truth)
    reference_truth: Clock | None = None  # the reference's, when the host is one
    notes: list[str] = field(default_factory=list)
    skipped: int = 0  # its /tf and /pose messages, left out (from /pose/sent again)

    @property
    def label(self) -> str:
        """``LAB/NAME``, or ``LAB/NAME.segN`` for a later segment: its records' prefix."""
        return self.agent if self.segment == 1 else f"{self.agent}.seg{self.segment}"

    def to_reference(self, t: float) -> float:
        """Own clock ``t`` (s) on reference time (s)."""
        if self.estimate is None or not self.estimate.n:
            return t
        return t + self.estimate.interp(t)

    def bound(self, t: float) -> float | None:
        """Error bound (s) of :meth:`to_reference` at own clock ``t``; None where unknown
        (before the agent's first estimate, or no status line said): the larger of the
        status lines' either side, plus the interpolation's."""
        if self.source == "reference":
            return 0.0
        estimate = self.estimate
        if estimate is None or not estimate.n or t < estimate.firsts[0] or not self.statuses.n:
            return None
        near = [b for b in self.statuses.near(t, _BOUND) if math.isfinite(b)]
        return max(near) + 2 * THIN_S if near else None

    def _size(self) -> int | None:
        try:
            return self.path.stat().st_size
        except OSError:
            return None

    def from_wall(self, wall_ns: int) -> float | None:
        """Own clock (s) at a log time (host wall clock, ns), by the wall line."""
        if self.wall is None:
            return None
        a, b = self.wall
        return a + b * wall_ns / 1e9

    def describe(self) -> dict[str, Any]:
        """As a metadata record's data (JSON-ready): a summary of the clock; its points
        are the ``/LAB/NAME/clock`` rows (``point`` true: the estimate's, linear
        between; false: at a status line, with the bound)."""
        points = self.estimate.n if self.estimate is not None else 0
        return {
            "file": self.path.name, "segment": self.segment, "size_bytes": self._size(),
            "reference": self.reference, "source": self.source,
            "offset_points": points, "status_lines": self.statuses.n,
            "reference_bound_max_s": self.bound_max,
            "clock_channel": f"/{self.agent}/clock",
            "wall_line": json.dumps(self.wall), "wall_residual_s": self.wall_residual,
            "host_truth_line": json.dumps(self.truth), "host": self.host,
            "started_ref_s": self.started, "thinning_bound_s": 2 * THIN_S,
        }  # fmt: skip

    def close(self) -> None:
        """Delete its temporary files."""
        self.statuses.close()
        if self.estimate is not None:
            self.estimate.close()


_MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # a record's opcode and length
_CHUNK = struct.Struct("<QQQII")  # a chunk's start, end, size, CRC; its compression's length
_READ = frozenset({Opcode.CHUNK, Opcode.MESSAGE, Opcode.CHANNEL, Opcode.SCHEMA, Opcode.METADATA})
_MESSAGE = struct.Struct("<HIQQ")  # a message's channel, sequence, log and publish time


def _stream(
    f: IO[bytes], topics: Sequence[str] | None, metadata: dict[str, dict[str, str]] | None
) -> Iterator[tuple[Schema | None, McapChannel, McapMessage]]:
    """(schema, channel, message) of an MCAP stream in file order, its metadata records
    into ``metadata`` (if given), up to its footer. File order, not log-time order:
    ordering by log time would load the file's whole chunk index (its summary). The
    records a merge does not use (indexes, statistics, attachments) are skipped unread.

    Raises
    ------
    ValueError
        When it is not MCAP, or ends before its footer (cut short).
    """
    if f.read(len(_MAGIC)) != _MAGIC:
        raise ValueError("not an MCAP file (no magic at its start)")
    schemas: dict[int, Schema] = {}
    channels: dict[int, McapChannel] = {}
    wanted = None if topics is None else frozenset(topics)
    while True:
        head = f.read(_RECORD.size)
        if len(head) < _RECORD.size:
            raise ValueError("the file ends before its footer (cut short)")
        opcode, length = _RECORD.unpack(head)
        if opcode == Opcode.FOOTER:
            return
        if opcode not in _READ or (opcode == Opcode.METADATA and metadata is None):
            f.seek(length, io.SEEK_CUR)
            continue
        body = f.read(length)
        if len(body) < length:
            raise ValueError(f"a record of {length} bytes is cut short")
        if opcode == Opcode.CHUNK:
            yield from _chunk(_chunk_data(body), schemas, channels, wanted)
        elif opcode == Opcode.MESSAGE:  # one outside a chunk
            yield from _chunk(head + body, schemas, channels, wanted)
        else:
            _declare(opcode, body, schemas, channels, metadata)


def _declare(
    opcode: int,
    body: bytes,
    schemas: dict[int, Schema],
    channels: dict[int, McapChannel],
    metadata: dict[str, dict[str, str]] | None,
) -> None:
    """A schema, channel or metadata record, kept."""
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHANNEL:
        channel = McapChannel.read(stream)
        channels[channel.id] = channel
    elif opcode == Opcode.SCHEMA:
        schema = Schema.read(stream)
        schemas[schema.id] = schema
    elif opcode == Opcode.METADATA and metadata is not None:
        record = Metadata.read(stream)
        metadata[record.name] = dict(record.metadata)


def _chunk_data(body: bytes) -> bytes:
    """A chunk record's records, decompressed."""
    start, end, size, crc, length = _CHUNK.unpack_from(body)
    at = _CHUNK.size + length
    compression = body[_CHUNK.size : at].decode()
    (records,) = struct.unpack_from("<Q", body, at)
    chunk = Chunk(
        message_start_time=start, message_end_time=end, uncompressed_size=size,
        uncompressed_crc=crc, compression=compression, data=body[at + 8 : at + 8 + records],
    )  # fmt: skip
    stream, size = get_chunk_data_stream(chunk)
    return stream.read(size)


def _chunk(
    data: bytes,
    schemas: dict[int, Schema],
    channels: dict[int, McapChannel],
    wanted: frozenset[str] | None,
) -> Iterator[tuple[Schema | None, McapChannel, McapMessage]]:
    """A chunk's messages (its schemas and channels registered on the way), parsed with
    one unpack a message: what the mcap library's reader does a field at a time, and a
    message of a topic not ``wanted`` is skipped before its data is copied."""
    size, at = len(data), 0
    while at < size:
        opcode, length = _RECORD.unpack_from(data, at)
        body, at = at + _RECORD.size, at + _RECORD.size + length
        if at > size:
            raise ValueError(f"a record of {length} bytes runs past its chunk's end")
        if opcode == Opcode.MESSAGE:
            channel_id, sequence, log_time, publish_time = _MESSAGE.unpack_from(data, body)
            channel = channels.get(channel_id)
            if channel is None:
                raise ValueError(f"message on channel {channel_id}, never declared")
            if wanted is None or channel.topic in wanted:
                message = McapMessage(
                    channel_id=channel_id, sequence=sequence, log_time=log_time,
                    publish_time=publish_time, data=data[body + _MESSAGE.size : at],
                )  # fmt: skip
                yield schemas.get(channel.schema_id), channel, message
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            _declare(opcode, data[body:at], schemas, channels, None)


def stream_messages(
    path: Path,
    topics: Sequence[str] | None,
    notes: list[str],
    metadata: dict[str, dict[str, str]] | None = None,
) -> Iterator[tuple[Schema | None, McapChannel, McapMessage]]:
    """(schema, channel, message) of a recording in file order (the recorder writes
    them in log-time order); from a damaged file (its agent killed), up to the damage
    (a note says so). ``metadata`` gets its metadata records if it reads to its end."""
    records: dict[str, dict[str, str]] = {}
    with path.open("rb") as f:
        try:
            yield from _stream(f, topics, records)
        except Exception as error:  # mcap raises many kinds on damage
            notes.append(f"{path.name}: damaged ({type(error).__name__}); read up to it")
            return
    if metadata is not None:
        metadata.update(records)


class _Survey:
    """What the first pass gathers of one recording, topic by topic."""

    def __init__(self, clock: AgentClock):
        self.clock = clock
        self.own, self.exchanges = Thinned(), Thinned()
        self.references: Counter[str] = Counter()

    def reference(self, t: float, data: dict[str, Any], log_time: int) -> None:
        t_sim = number(data.get("t_sim"))
        if t_sim is not None:
            self.own.add(t, t_sim - t)

    def status(self, t: float, data: dict[str, Any], log_time: int) -> None:
        clock = self.clock
        if isinstance(data.get("agent"), str):
            clock.agent = data["agent"]
        if isinstance(data.get("reference"), str):
            self.references[data["reference"]] += 1
        ready = data.get("ready")
        bound = number(ready.get("reference_bound")) if isinstance(ready, dict) else None
        if bound is not None and data.get("reference") != data.get("agent"):
            # The estimate's own bound leaves out the path: its stamps' bound is the
            # one-way delay to the reference plus it, as the agent's pose stamps state.
            peers = data.get("peers")
            peer = peers.get(data.get("reference")) if isinstance(peers, dict) else None
            delay = number(peer.get("delay")) if isinstance(peer, dict) else None
            bound = None if delay is None else bound + delay
        if bound is not None:
            clock.bound_max = bound if clock.bound_max is None else max(clock.bound_max, bound)
        host = number(data.get("host_monotonic"))
        clock.statuses.append(
            t, math.nan if bound is None else bound, log_time / 1e9,
            math.nan if host is None else host,
        )  # fmt: skip

    def control(self, t: float, data: dict[str, Any], log_time: int) -> None:
        at = number(data.get("at"))
        if data.get("event") == "started" and at is not None and self.clock.started is None:
            self.clock.started = at

    def exchange(self, t: float, data: dict[str, Any], log_time: int) -> None:
        estimate = number(data.get("estimate"))
        if estimate is not None:
            self.exchanges.add(t, estimate)  # the reference's, if it is the only peer

    def finish(self) -> AgentClock:
        clock = self.clock
        clock.reference = self.references.most_common(1)[0][0] if self.references else None
        if clock.reference == clock.agent:
            clock.source = "reference"
        elif len(self.own):
            clock.source, clock.estimate = "estimate", self.own.finish()
        elif len(self.exchanges):
            clock.source, clock.estimate = "exchanges", self.exchanges.finish()
        for unused in (self.own, self.exchanges):
            if unused.kept is not clock.estimate:
                unused.kept.close()
        t = clock.statuses.column(_T)
        clock.wall, clock.wall_residual = _line(t, clock.statuses.column(_WALL))
        host = clock.statuses.column(_HOST)
        known = np.isfinite(host)
        clock.truth, _ = _line(t[known], host[known])
        return clock


def survey(path: Path) -> AgentClock:
    """The first pass over one recording: who recorded it, its offset estimate of the
    reference clock (thinned), its status lines' bounds, wall and host times."""
    clock = AgentClock(agent_from_filename(path), path, segment_of(path))
    gather = _Survey(clock)
    handlers: dict[str, Callable[[float, dict[str, Any], int], None]] = {
        Channel.REFERENCE: gather.reference, Channel.STATUS: gather.status,
        Channel.CONTROL: gather.control, Channel.SYNC_EXCHANGE: gather.exchange,
    }  # fmt: skip
    for _schema, channel, message in stream_messages(path, _SURVEYED, clock.notes, clock.metadata):
        try:
            data = json.loads(message.data)
        except ValueError:
            continue
        t = number(data.get(STAMP_FIELDS[channel.topic])) if isinstance(data, dict) else None
        if t is None:
            continue
        if clock.first is None:
            clock.first = t
        handlers[channel.topic](t, data, message.log_time)
    gather.finish()
    clock.host = (clock.metadata.get("fedlab.run") or {}).get("host") or None
    return clock


def _line(t: np.ndarray, x: np.ndarray) -> tuple[Clock | None, float]:
    """The clock line ``t = a + b * x`` through status lines and its largest residual
    (fitted as :func:`federation.report.status.clock_line` fits it, on arrays)."""
    if len(t) < 2 or x[0] == x[-1]:
        return None, 0.0
    b, a = np.polyfit(x - x[0], t - t[0], 1)
    line = (float(t[0] + a - b * x[0]), float(b))
    residual = float(np.max(np.abs(t - (line[0] + line[1] * x))))
    return line, residual


@dataclass
class Epoch:
    """The run's start: on reference time (``start``, s) and in UTC as the hosts' wall
    clocks say it (``ns``), with its uncertainty (s)."""

    start: float
    ns: int
    uncertainty: float | None
    hosts: dict[str, float]  # per agent: its host's wall clock at reference 0, s

    def log_time(self, t_ref: float) -> int:
        return self.ns + round((t_ref - self.start) * 1e9)


def epoch(clocks: Sequence[AgentClock], notes: list[str]) -> Epoch:
    """The run's start on reference time and in UTC: the reference's started event (else
    any agent's, else the earliest stamp), and each host's wall clock at it."""
    starts = [c.started for c in clocks if c.source == "reference" and c.started is not None]
    starts += [c.started for c in clocks if c.started is not None]
    if starts:
        start = starts[0]
    else:
        firsts = [c.to_reference(c.first) for c in clocks if c.first is not None]
        start = min(firsts) if firsts else 0.0
        notes.append("no started event: the epoch is the first stamp recorded")
    hosts: dict[str, float] = {}
    scatter = 0.0
    for c in clocks:
        if c.source == "none" or not c.statuses.n:
            continue
        zeros = np.fromiter(
            (w - c.to_reference(t) for columns in c.statuses.rows()
             for t, w in zip(columns[_T].tolist(), columns[_WALL].tolist(), strict=True)),
            dtype=float, count=c.statuses.n,
        )  # fmt: skip
        hosts[c.label] = float(np.median(zeros))
        scatter = max(scatter, float(zeros.max() - zeros.min()) / 2)
    if not hosts:
        notes.append("no status line: the epoch's UTC is unknown (log time 0 is the start)")
        return Epoch(start, 0, None, {})
    zero = statistics.median(hosts.values())
    spread = max(abs(v - zero) for v in hosts.values())
    ns = round(zero * 1e9) + round(start * 1e9)
    return Epoch(start, ns, spread + scatter, hosts)

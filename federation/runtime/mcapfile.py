"""The recordings' MCAP files as files: reading their JSON messages and metadata,
telling a finished file from a cut one, and salvaging a cut one.

:func:`read_messages` reads the JSON channels of a recording (old and new files);
:func:`read_metadata` its metadata records, which :func:`as_metadata` and
:func:`from_metadata` turn from and to JSON-ready data. :func:`is_finished` tells a
finished file (its agent killed after closing it, before its manifest was written)
from a cut one; :func:`salvage` copies every complete record of an unfinished file
(its agent killed, its host's power lost: no summary, a chunk cut short, zeros or
garbage after the last record) into a finished one. The writer of recordings is
:class:`federation.runtime.recorder.Recorder`.
"""

from __future__ import annotations

import io
import json
import os
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Chunk, McapRecord, Metadata, Schema
from mcap.records import Channel as McapChannel
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk
from mcap.writer import MCAP0_MAGIC, Writer

from federation.core.channels import Channel

__all__ = [
    "CHUNK_SIZE",
    "RECORDING_METADATA",
    "RECOVERY_METADATA",
    "Salvage",
    "as_metadata",
    "from_metadata",
    "is_finished",
    "read_messages",
    "read_metadata",
    "salvage",
]

CHUNK_SIZE = 64 * 1024
"""Bytes of messages gathered (uncompressed) before they are compressed and written as
one chunk, in every recording (a recorder's, a salvaged one). An agent killed mid-run
loses at most the last chunk, and each recorder holds one in memory with its index: a
follower's 5 to 6 kB a second fill 64 kB in about 12 s. Larger chunks cost memory: at
256 kB, 32 followers' chunks take about 13 MiB of their worker."""
RECORDING_METADATA = "fedlab.recording"
"""Name of the metadata record a recorder writes at close: messages written, whether it
was truncated, what was dropped."""
RECOVERY_METADATA = "fedlab.recovery"
"""Name of the metadata record :func:`salvage` adds: what it read of the damaged file."""


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


def is_finished(path: Path) -> bool:
    """Whether ``path`` is a finished MCAP file: the magic at both ends, a footer whose
    summary reads, and each chunk its index lists where it says. A recorder closed it
    (its agent killed before the manifest was written): not a file cut short."""
    try:
        with Path(path).open("rb") as f:
            f.seek(-len(MCAP0_MAGIC), io.SEEK_END)
            if f.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
                return False
            f.seek(0)
            summary = make_reader(f).get_summary()  # the magic at its start checked
            if summary is None:
                return False
            for index in summary.chunk_indexes:
                f.seek(index.chunk_start_offset)
                if f.read(1) != bytes([Opcode.CHUNK]):
                    return False
    except Exception:  # short, cut, garbage: mcap raises many kinds (struct, EOF, McapError)
        return False
    return True


_OPCODES = frozenset(int(o) for o in Opcode)
_RECORD_LIMIT = 256 << 20
"""Bytes: no record of a recording is longer (a chunk holds about CHUNK_SIZE); a longer
length is damage, not a record to load into memory."""
_COPIED: dict[int, Any] = {
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: McapChannel.read,
    Opcode.METADATA: Metadata.read,
    Opcode.ATTACHMENT: Attachment.read,
}
"""The records besides chunks and messages that a salvaged file keeps; the others
(header, indexes, statistics, summary) are written anew."""


@dataclass
class Salvage:
    """What :func:`salvage` read of a damaged recording."""

    size: int = 0  # bytes of the damaged file
    readable: int = 0  # bytes up to the end of its last complete record
    messages: int = 0  # messages copied
    chunks_lost: int = 0  # complete chunks that could not be read (CRC, compression)
    records_lost: int = 0  # other unreadable records, and messages of a channel lost
    whole: bool = False  # its data section ended properly: nothing was cut off
    problem: str = ""  # where and why reading stopped ("" when whole)

    def report(self) -> dict[str, Any]:
        """As JSON-ready data."""
        return {
            "recovered": True,
            "end_missing": not self.whole,
            "messages": self.messages,
            "chunks_lost": self.chunks_lost,
            "records_lost": self.records_lost,
            "original_bytes": self.size,
            "readable_bytes": self.readable,
            "problem": self.problem,
        }

    def metadata(self) -> dict[str, str]:
        """As MCAP metadata (:func:`as_metadata`)."""
        return as_metadata(self.report())


def as_metadata(data: dict[str, Any]) -> dict[str, str]:
    """JSON-ready data as an MCAP metadata record's: every value a string (``12``,
    ``true``, ``""`` for None)."""
    return {k: _text(v) for k, v in data.items()}


def _text(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def from_metadata(record: dict[str, str]) -> dict[str, Any]:
    """An MCAP metadata record written by :func:`as_metadata` as JSON-ready data again:
    ``true``/``false`` as booleans, integers as integers, ``""`` as None."""
    out: dict[str, Any] = {}
    for key, text in record.items():
        if text in ("true", "false"):
            out[key] = text == "true"
        elif text == "":
            out[key] = None
        else:
            try:
                out[key] = int(text)
            except ValueError:
                out[key] = text
    return out


def salvage(
    damaged: Path,
    out: Path,
    note: dict[str, str] | None = None,
    stop: Callable[[], bool] | None = None,
) -> Salvage:
    """Write every complete record of an unfinished recording ``damaged`` into a finished
    one, ``out``: schemas, channels, messages, metadata and attachments in their order,
    with a new index and summary, and a ``fedlab.recovery`` metadata record (``note``
    and what was read: :meth:`Salvage.metadata`).

    Reading stops at the first record cut short or that is not an MCAP record (zeros or
    garbage a lost power left); a chunk whose CRC, compression or records are bad is
    left out and counted, and reading goes on after it. A file that is empty or not an
    MCAP at all gives a finished file with no message. Raises only ``OSError`` (reading
    or writing failed; ``InterruptedError`` when ``stop`` is set, or returns True: it is
    asked before each record), never on the content; ``out`` is then left as it is.
    Memory holds one chunk at a time; the interpreter is yielded after each record, so
    that an agent's loop on another thread keeps its pace.
    """
    result = Salvage(size=damaged.stat().st_size)
    with damaged.open("rb") as source, out.open("wb") as sink:
        writer = Writer(sink, chunk_size=CHUNK_SIZE)
        writer.start(profile="", library="fedlab")
        copy = _Copier(writer, result)
        for opcode, body in _records(source, result):
            if stop is not None and stop():
                raise InterruptedError(f"salvaging {damaged}: stopped")
            if opcode == Opcode.DATA_END:
                result.whole = True
                break
            try:
                records = _parse(opcode, body)
            except Exception:  # mcap raises many kinds on damage (CRC, zstd, struct, EOF)
                if opcode == Opcode.CHUNK:
                    result.chunks_lost += 1
                else:
                    result.records_lost += 1
                continue
            for record in records:
                copy(record)
            time.sleep(0)  # let a waiting thread (the agent's loop) take the interpreter
        writer.add_metadata(RECOVERY_METADATA, (note or {}) | result.metadata())
        writer.finish()  # type: ignore[no-untyped-call]
        sink.flush()
        os.fsync(sink.fileno())  # on disk before it is renamed into place
    return result


def _records(source: IO[bytes], result: Salvage) -> Iterator[tuple[int, bytes]]:
    """(opcode, body) of every complete record after the magic, up to the first that is
    cut short or cannot be a record (``result.problem`` says where)."""
    if result.size == 0:
        result.problem = "the file is empty: nothing of it reached the disk"
        return
    if source.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
        result.problem = "not an MCAP file (no MCAP magic at its start)"
        return
    offset = result.readable = len(MCAP0_MAGIC)
    while True:
        head = source.read(9)
        if not head:
            result.problem = f"the file ends after its last complete record, at byte {offset}"
            return
        if len(head) < 9:
            result.problem = f"cut inside a record's header at byte {offset}"
            return
        opcode, length = struct.unpack("<BQ", head)
        if opcode not in _OPCODES:
            result.problem = f"no MCAP record at byte {offset} (zeros or garbage from there)"
            return
        name = Opcode(opcode).name.lower()
        if length > _RECORD_LIMIT:
            result.problem = f"a {name} record of {length} bytes at byte {offset}: damaged"
            return
        body = source.read(length)
        if len(body) < length:
            result.problem = f"cut inside a {name} record at byte {offset}"
            return
        offset = result.readable = offset + 9 + length
        yield opcode, body


def _parse(opcode: int, body: bytes) -> list[McapRecord]:
    """The records to copy from one record: a chunk's (its CRC checked), or itself."""
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(stream)
        if chunk.uncompressed_size > _RECORD_LIMIT:
            raise ValueError(f"a chunk of {chunk.uncompressed_size} bytes: damaged")
        return breakup_chunk(chunk, validate_crc=True)
    if opcode == Opcode.MESSAGE:
        return [McapMessage.read(stream, len(body))]
    read = _COPIED.get(opcode)
    return [] if read is None else [read(stream)]


class _Copier:
    """Writes the records read into the salvaged file, each schema and channel once,
    under the ids the new file gives them."""

    def __init__(self, writer: Writer, result: Salvage):
        self.writer = writer
        self.result = result
        self.schemas: dict[int, int] = {0: 0}  # the damaged file's ids -> the new file's
        self.channels: dict[int, int] = {}

    def __call__(self, record: McapRecord) -> None:
        writer = self.writer
        if isinstance(record, McapMessage):
            channel = self.channels.get(record.channel_id)
            if channel is None:  # its channel was in a chunk that is lost
                self.result.records_lost += 1
                return
            writer.add_message(
                channel, record.log_time, record.data, record.publish_time, record.sequence
            )
            self.result.messages += 1
        elif isinstance(record, Schema):
            if record.id not in self.schemas:
                self.schemas[record.id] = writer.register_schema(
                    record.name, record.encoding, record.data
                )
        elif isinstance(record, McapChannel):
            if record.id not in self.channels:
                self.channels[record.id] = writer.register_channel(
                    record.topic, record.message_encoding,
                    self.schemas.get(record.schema_id, 0), record.metadata,
                )  # fmt: skip
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, record.metadata)
        elif isinstance(record, Attachment):
            writer.add_attachment(
                record.create_time, record.log_time, record.name, record.media_type, record.data
            )

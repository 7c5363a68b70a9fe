"""Fetching a file in chunks over queries, free of I/O: requests, checks, resumption.

An agent serves its finished recordings on ``fedlab/<fed>/<lab>/<name>/recordings``
(:mod:`federation.runtime.collect`). A query's parameters say what is wanted::

    run=<run-id>                                  the run's manifest (JSON)
    run=<run-id>;file=<name>;offset=<n>;length=<n>  bytes [n, n + length) of a file

A chunk's reply carries its SHA-256 in the attachment (:func:`chunk_attachment`);
the collector checks each chunk's length and digest (:func:`check_chunk`),
fetches a bad one again, and the whole file's SHA-256 against the manifest at
the end. A partial download (``<name>.part``) resumes at its length, rounded
down to a chunk boundary (:func:`resume_offset`).

Names are checked here (:func:`safe_name`): a request can never leave the run's
folder, whatever it asks for.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass

__all__ = [
    "ChunkRequest",
    "RequestError",
    "check_chunk",
    "chunk_attachment",
    "format_request",
    "parse_request",
    "read_attachment",
    "resume_offset",
    "safe_name",
]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,199}")
MAX_OFFSET = 2**53
"""The largest offset a request may give (bytes): exact as a JSON number, far beyond
any recording; a larger one would raise in seek() (a traceback logged per query)."""
MAX_LENGTH = 48 << 10
"""The largest chunk a request may ask for (bytes): a reply must fit one Zenoh batch
(64 KiB) with its key and attachment, since the low-latency transport cannot fragment."""


class RequestError(ValueError):
    """A request that cannot be served: what is wrong with it."""


def safe_name(value: str, what: str) -> str:
    """``value`` if it is a plain file or run name (letters, digits, ``.``, ``_``,
    ``-``; not starting with a dot), else :class:`RequestError`."""
    if not _NAME.fullmatch(value) or ".." in value:
        raise RequestError(f"{what} {value!r} is not a plain name")
    return value


@dataclass(frozen=True)
class ChunkRequest:
    """A run's manifest (``file`` None) or ``length`` bytes of ``file`` at ``offset``."""

    run: str
    file: str | None = None
    offset: int = 0
    length: int = 0


def format_request(request: ChunkRequest) -> str:
    """The query parameters of ``request``."""
    if request.file is None:
        return f"run={request.run}"
    return f"run={request.run};file={request.file};offset={request.offset};length={request.length}"


def parse_request(parameters: str) -> ChunkRequest:
    """A query's parameters as a :class:`ChunkRequest`; :class:`RequestError` if bad."""
    fields: dict[str, str] = {}
    for item in filter(None, parameters.split(";")):
        key, sep, value = item.partition("=")
        if not sep:
            raise RequestError(f"parameter {item!r} is not KEY=VALUE")
        fields[key] = value
    if "run" not in fields:
        raise RequestError("no run=<run-id> parameter")
    run = safe_name(fields["run"], "run")
    if "file" not in fields:
        return ChunkRequest(run)
    name = safe_name(fields["file"], "file")
    try:
        offset, length = int(fields.get("offset", "0")), int(fields.get("length", "0"))
    except ValueError:
        raise RequestError("offset and length must be integers") from None
    if not 0 <= offset <= MAX_OFFSET or not 0 < length <= MAX_LENGTH:
        raise RequestError(f"offset {offset} / length {length} out of range (<= {MAX_LENGTH})")
    return ChunkRequest(run, name, offset, length)


def chunk_attachment(offset: int, data: bytes) -> bytes:
    """What a chunk's reply carries beside it: its offset (8 bytes) and SHA-256."""
    return offset.to_bytes(8, "big") + hashlib.sha256(data).digest()


def read_attachment(attachment: bytes) -> tuple[int, bytes]:
    """(offset, SHA-256) of a chunk's attachment; :class:`RequestError` if malformed."""
    if len(attachment) != 40:
        raise RequestError(f"chunk attachment of {len(attachment)} bytes, expected 40")
    return int.from_bytes(attachment[:8], "big"), attachment[8:]


def check_chunk(
    data: bytes, attachment: bytes | None, offset: int, expected_length: int
) -> str | None:
    """Why a received chunk is bad (None if good): ``truncated`` (shorter than asked
    for, before the file's end), ``too long``, ``wrong offset``, ``corrupted`` (its
    bytes do not match the digest the server sent) or ``no digest``."""
    if attachment is None:
        return "no digest"
    try:
        at, digest = read_attachment(attachment)
    except RequestError:
        return "no digest"
    if at != offset:
        return "wrong offset"
    if len(data) < expected_length:
        return "truncated"
    if len(data) > expected_length:
        return "too long"
    if hashlib.sha256(data).digest() != digest:
        return "corrupted"
    return None


def resume_offset(partial: int, size: int, chunk: int) -> int:
    """Where to resume a download of ``size`` bytes of which ``partial`` are on disk:
    the last chunk boundary at or below it (a half-written chunk is fetched again)."""
    if partial >= size:
        return size if partial == size else 0
    return (partial // chunk) * chunk

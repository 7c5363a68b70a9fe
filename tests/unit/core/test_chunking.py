"""Chunked fetches (federation/core/chunking.py): requests, checks, resumption."""

from __future__ import annotations

import hashlib

import pytest

from federation.core.chunking import (
    ChunkRequest,
    RequestError,
    check_chunk,
    chunk_attachment,
    format_request,
    parse_request,
    resume_offset,
)


def test_requests_round_trip() -> None:
    for request in (ChunkRequest("run-1"), ChunkRequest("run-1", "a-b.mcap", 1 << 20, 4096)):
        assert parse_request(format_request(request)) == request


@pytest.mark.parametrize(
    "parameters",
    [
        "",
        "file=x",
        "run=../etc",
        "run=r;file=../../passwd;offset=0;length=1",
        "run=r;file=.hidden;offset=0;length=1",
        "run=r;file=a/b;offset=0;length=1",
        "run=r;file=f;offset=-1;length=1",
        "run=r;file=f;offset=0;length=0",
        "run=r;file=f;offset=0;length=999999999",
        "run=r;file=f;offset=x;length=1",
        "run",
        "run=r;file=f;offset=4611686018427387904;length=1",  # seek() raised on it
        "run=abc\n",  # a trailing newline had passed as a plain name
    ],
)
def test_bad_requests_are_refused(parameters: str) -> None:
    with pytest.raises(RequestError):
        parse_request(parameters)


def test_a_good_chunk_passes() -> None:
    data = b"x" * 100
    assert check_chunk(data, chunk_attachment(300, data), 300, 100) is None


def test_corrupted_truncated_and_misplaced_chunks_are_caught() -> None:
    data = bytes(range(256)) * 4
    attachment = chunk_attachment(0, data)
    flipped = bytearray(data)
    flipped[17] ^= 0x01
    assert check_chunk(bytes(flipped), attachment, 0, len(data)) == "corrupted"
    assert check_chunk(data[:-1], attachment, 0, len(data)) == "truncated"
    assert check_chunk(data + b"!", attachment, 0, len(data)) == "too long"
    assert check_chunk(data, chunk_attachment(1024, data), 0, len(data)) == "wrong offset"
    assert check_chunk(data, None, 0, len(data)) == "no digest"
    assert check_chunk(data, hashlib.sha256(data).digest(), 0, len(data)) == "no digest"


def test_resume_at_the_last_whole_chunk() -> None:
    assert resume_offset(0, 100, 10) == 0
    assert resume_offset(35, 100, 10) == 30
    assert resume_offset(100, 100, 10) == 100
    assert resume_offset(150, 100, 10) == 0  # longer than the file: start again

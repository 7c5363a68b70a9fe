"""The TCP relay's half-close passed on to a destination whose peer is gone already:
the socket refuses the EOF (ENOTCONN), and the relay closes it; nothing is raised out
of the event loop's timer callback that drained the queue."""

from __future__ import annotations

import asyncio
import errno
import random
from types import SimpleNamespace
from typing import Any

from federation.link.model import DirectionModel
from federation.link.stats import DirectionStats
from federation.link.tcp import _StreamPipe
from schemas.link import DirectionConfig


class _Transport:
    def __init__(self, eof_error: OSError | None) -> None:
        self.eof_error = eof_error
        self.closed = False
        self.eof_written = False

    def is_closing(self) -> bool:
        return self.closed

    def can_write_eof(self) -> bool:
        return True

    def write_eof(self) -> None:
        if self.eof_error is not None:
            raise self.eof_error
        self.eof_written = True

    def close(self) -> None:
        self.closed = True


def pipe(dst: _Transport) -> tuple[_StreamPipe, list[str]]:
    ended: list[str] = []
    loop = asyncio.new_event_loop()
    relay: Any = SimpleNamespace(loop=loop)
    src: Any = SimpleNamespace(
        transport=None, conn=SimpleNamespace(pipe_ended=lambda: ended.append("src"))
    )
    side: Any = SimpleNamespace(transport=dst)
    model = DirectionModel(DirectionConfig(), random.Random(1))
    out = _StreamPipe(relay, model, DirectionStats(), src, side)
    loop.close()
    return out, ended


def test_a_half_close_is_passed_on() -> None:
    dst = _Transport(None)
    p, ended = pipe(dst)
    p.finish(close=False)
    assert dst.eof_written and not dst.closed and ended == ["src"]


def test_a_half_close_to_a_gone_peer_closes_the_destination() -> None:
    dst = _Transport(OSError(errno.ENOTCONN, "Transport endpoint is not connected"))
    p, ended = pipe(dst)
    p.finish(close=False)
    assert dst.closed and ended == ["src"]

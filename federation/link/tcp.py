"""The TCP relay: each accepted connection relayed to its own connection to the target.

Per connection and direction a :class:`_StreamPipe` delays the chunks read
(:class:`~federation.link.model.StreamScheduler`: never reordered, never lost).
A half-close travels through once what is queued before it is delivered; a reset
or close of one side closes the other after its queue drains. Reading a side stops
while its pipe is over the queue cap or the other side's write buffer is full.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Literal

from federation.link.model import DirectionModel, StreamScheduler
from federation.link.relay import MAX_SESSIONS, Relay, TimedQueue, endpoint_error
from federation.link.stats import DirectionStats
from schemas.link import LinkEndpoint

__all__ = ["serve_tcp"]

log = logging.getLogger("fedlab.link")

_DIAL_TIMEOUT = 10.0  # s to connect to the target before the client is closed


class _StreamPipe(TimedQueue[None]):
    """One direction of one TCP connection, from ``src`` into ``dst``."""

    def __init__(
        self,
        relay: Relay,
        model: DirectionModel,
        stats: DirectionStats,
        src: _TcpSide,
        dst: _TcpSide,
    ):
        super().__init__(relay, stats)
        self.schedule = StreamScheduler(model)
        self.src = src
        self.dst = dst
        self.writer_blocked = False
        self.reading_paused = False
        self.eof = False
        self.close_dst = False
        self.ended = False
        self.dead = False

    def feed(self, data: bytes) -> None:
        if self.dead or self.eof:
            return
        now = self.loop.time()
        self.stats.read(len(data))
        self.put(self.schedule.deliver_at(now), now, None, data)

    def deliver(self, item: None, data: bytes) -> None:
        transport = self.dst.transport
        if transport is not None:
            transport.write(data)
            self.stats.deliver(len(data))

    def hold_source(self, hold: bool) -> None:
        self._update_reading()

    def drained(self) -> None:
        if self.eof and not self.dead:
            self._end()

    def set_writer_blocked(self, blocked: bool) -> None:
        self.writer_blocked = blocked
        self._update_reading()

    def _update_reading(self) -> None:
        pause = (self.full or self.writer_blocked) and not self.dead
        transport = self.src.transport
        if pause == self.reading_paused or transport is None:
            return
        self.reading_paused = pause
        if pause:
            self.stats.pauses += 1
            transport.pause_reading()
        else:
            transport.resume_reading()

    def finish(self, close: bool) -> None:
        """The source has ended: after the queue drains, end (or close) the destination."""
        self.eof = True
        self.close_dst = self.close_dst or close
        if not self.heap and not self.dead:
            self._end()

    def _end(self) -> None:
        if self.ended:
            return
        self.ended = True
        transport = self.dst.transport
        if transport is not None and not transport.is_closing():
            if self.close_dst or not transport.can_write_eof():
                transport.close()
            else:
                try:
                    transport.write_eof()
                except OSError:  # the destination's peer is gone already (ENOTCONN)
                    transport.close()
        self.src.conn.pipe_ended()

    def abort(self) -> None:
        """Drop what is queued (its destination is gone)."""
        self.dead = True
        self.clear()


class _TcpSide(asyncio.Protocol):
    """One socket of a relayed connection: ``a`` accepted, ``b`` dialled to the target."""

    def __init__(self, conn: _TcpConnection, name: Literal["a", "b"]):
        self.conn = conn
        self.name = name
        self.transport: asyncio.Transport | None = None
        self.out: _StreamPipe | None = None  # reads from this side
        self.into: _StreamPipe | None = None  # writes into this side
        self.lost = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.conn.made(self)

    def data_received(self, data: bytes) -> None:
        if self.out is not None:
            self.out.feed(data)

    def eof_received(self) -> bool:
        if self.out is not None:
            self.out.finish(close=False)
        return True  # keep the socket open: the other direction may still carry data

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = True
        self.conn.side_lost(self, exc)

    def pause_writing(self) -> None:
        if self.into is not None:
            self.into.set_writer_blocked(True)

    def resume_writing(self) -> None:
        if self.into is not None:
            self.into.set_writer_blocked(False)


class _TcpConnection:
    """An accepted connection ``a`` relayed to its own connection ``b`` to the target."""

    def __init__(self, relay: Relay, registry: set[_TcpConnection]):
        self.relay = relay
        self.registry = registry
        self.a = _TcpSide(self, "a")
        self.b = _TcpSide(self, "b")
        self.dial: asyncio.Task[None] | None = None
        self.closed = False
        self.peer = "?"

    def made(self, side: _TcpSide) -> None:
        relay = self.relay
        if side is self.a:
            assert side.transport is not None
            self.peer = str(side.transport.get_extra_info("peername"))
            if len(self.registry) >= MAX_SESSIONS:
                relay.stats.refused += 1
                log.warning("refusing %s: %d connections open", self.peer, MAX_SESSIONS)
                self.closed = True
                side.transport.abort()
                return
            self.registry.add(self)
            relay.stats.connections += 1
            relay.stats.active += 1
            side.transport.pause_reading()  # until the other end is connected
            self.dial = relay.loop.create_task(self._dial())
            return
        # b connected: wire both directions, then let a's bytes flow.
        assert self.a.transport is not None
        model = relay.model
        fwd = _StreamPipe(relay, model.forward, relay.stats.forward, self.a, self.b)
        bwd = _StreamPipe(relay, model.backward, relay.stats.backward, self.b, self.a)
        self.a.out = self.b.into = fwd
        self.b.out = self.a.into = bwd
        self.a.transport.resume_reading()

    async def _dial(self) -> None:
        target = self.relay.target
        try:
            await asyncio.wait_for(
                self.relay.loop.create_connection(lambda: self.b, target.host, target.port),
                _DIAL_TIMEOUT,
            )
        except (TimeoutError, OSError) as error:
            log.warning("cannot reach %s for %s: %s", target, self.peer, error)
            if self.a.transport is not None:
                self.a.transport.close()
            return
        if self.closed and self.b.transport is not None:
            self.b.transport.close()

    def pipe_ended(self) -> None:
        """Both directions half-closed and drained: close the connection."""
        fwd, bwd = self.a.out, self.b.out
        if fwd is not None and bwd is not None and fwd.ended and bwd.ended:
            self.close()

    def side_lost(self, side: _TcpSide, exc: Exception | None) -> None:
        if exc is not None:
            log.debug("connection %s side %s lost: %s", self.peer, side.name, exc)
        if side.into is not None:
            side.into.abort()
        if side.out is not None:
            side.out.finish(close=True)  # deliver what is queued, then close the other side
        other = self.b if side is self.a else self.a
        if side is self.a and self.dial is not None and not self.dial.done():
            self.closed = True
            self.dial.cancel()
        if other.transport is None or other.lost:
            self._forget()
        elif other.out is None:
            other.transport.close()

    def close(self) -> None:
        """Close both sockets now (what is queued is dropped)."""
        self.closed = True
        if self.dial is not None and not self.dial.done():
            self.dial.cancel()
        for side in (self.a, self.b):
            if side.into is not None:
                side.into.abort()
            if side.transport is not None and not side.transport.is_closing():
                side.transport.close()
        if self.b.transport is None:
            self._forget()

    def _forget(self) -> None:
        if self in self.registry:
            self.registry.discard(self)
            self.relay.stats.active -= 1


async def serve_tcp(relay: Relay, stop: asyncio.Event, ready: Callable[[str], None]) -> None:
    """Relay TCP connections until ``stop`` is set; ``ready`` gets the listening endpoint.

    Raises
    ------
    ConfigError
        If the listening endpoint cannot be bound.
    """
    connections: set[_TcpConnection] = set()

    def accept() -> _TcpSide:
        return _TcpConnection(relay, connections).a

    listen = relay.listen
    try:
        server = await relay.loop.create_server(
            accept, listen.host, listen.port, reuse_address=True
        )
    except OSError as error:
        raise endpoint_error("listen", relay.options.listen, "cannot listen", error) from None
    sockname = server.sockets[0].getsockname()
    ready(str(LinkEndpoint("tcp", sockname[0], sockname[1])))
    try:
        await stop.wait()
    finally:
        server.close()
        for conn in list(connections):
            conn.close()
        await server.wait_closed()
        for _ in range(3):  # let connection_lost callbacks run
            await asyncio.sleep(0)

"""The UDP relay: the datagrams of each client address relayed through a socket of
their own, so the target's replies find their way back.

One :class:`_DatagramQueue` per direction, for all clients together, delays the
datagrams (:class:`~federation.link.model.DatagramScheduler`: lost, held back to be
overtaken, or in order). A datagram that cannot be sent is counted ``dropped``, as a
real path loses it. Clients idle for ``udp_idle`` seconds are forgotten.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from federation.link.model import DatagramScheduler, DirectionModel
from federation.link.relay import MAX_SESSIONS, Relay, TimedQueue, endpoint_error
from federation.link.stats import DirectionStats
from schemas.link import LinkEndpoint

__all__ = ["serve_udp"]

log = logging.getLogger("fedlab.link")

_READ_BATCH = 64  # datagrams read per wake-up, so one side cannot starve the other
_MAX_DATAGRAM = 65536


@dataclass(eq=False, slots=True)
class _UdpSession:
    client: Any
    sock: socket.socket
    last: float
    closed: bool = False


class _DatagramQueue(TimedQueue[_UdpSession]):
    """One direction's datagrams by delivery time, for all clients."""

    def __init__(
        self,
        relay: Relay,
        model: DirectionModel,
        stats: DirectionStats,
        send: Callable[[_UdpSession, bytes], bool],
        pause: Callable[[bool], None],
    ):
        super().__init__(relay, stats)
        self.schedule = DatagramScheduler(model)
        self.send = send
        self.pause = pause

    def push(self, session: _UdpSession, data: bytes, now: float) -> None:
        self.stats.read(len(data))
        at = self.schedule.deliver_at(now)
        if at is not None:
            self.put(at, now, session, data)

    def deliver(self, item: _UdpSession, data: bytes) -> None:
        if not item.closed and self.send(item, data):
            self.stats.deliver(len(data))
        else:
            self.stats.dropped += 1

    def hold_source(self, hold: bool) -> None:
        if hold:
            self.stats.pauses += 1
        self.pause(hold)


class _UdpRelay:
    """Datagrams from each client address relayed through a socket of their own."""

    def __init__(self, relay: Relay, sock: socket.socket, target: tuple[Any, ...], family: int):
        self.relay = relay
        self.loop = relay.loop
        self.sock = sock
        self.target = target
        self.family = family
        self.sessions: dict[Any, _UdpSession] = {}
        self.paused_fwd = False
        self.paused_bwd = False
        model, stats = relay.model, relay.stats
        self.fwd = _DatagramQueue(relay, model.forward, stats.forward, self._send_fwd, self._pf)
        self.bwd = _DatagramQueue(relay, model.backward, stats.backward, self._send_bwd, self._pb)
        self.loop.add_reader(sock.fileno(), self._on_listen)

    def _send_fwd(self, session: _UdpSession, data: bytes) -> bool:
        try:
            session.sock.send(data)
        except OSError:  # full buffer or ICMP error: a datagram is lost, as on a real path
            return False
        return True

    def _send_bwd(self, session: _UdpSession, data: bytes) -> bool:
        try:
            self.sock.sendto(data, session.client)
        except OSError:
            return False
        return True

    def _pf(self, pause: bool) -> None:
        self.paused_fwd = pause
        if pause:
            self.loop.remove_reader(self.sock.fileno())
        else:
            self.loop.add_reader(self.sock.fileno(), self._on_listen)

    def _pb(self, pause: bool) -> None:
        self.paused_bwd = pause
        for session in self.sessions.values():
            if pause:
                self.loop.remove_reader(session.sock.fileno())
            else:
                self.loop.add_reader(session.sock.fileno(), self._on_reply, session)

    def _on_listen(self) -> None:
        for _ in range(_READ_BATCH):
            try:
                data, addr = self.sock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                log.debug("udp receive: %s", error)
                return
            now = self.loop.time()
            session = self.sessions.get(addr)
            if session is None:
                session = self._open(addr, now)
                if session is None:
                    self.relay.stats.forward.dropped += 1
                    continue
            session.last = now
            self.fwd.push(session, data, now)

    def _open(self, addr: Any, now: float) -> _UdpSession | None:
        stats = self.relay.stats
        if len(self.sessions) >= MAX_SESSIONS:
            stats.refused += 1
            return None
        sock = socket.socket(self.family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.connect(self.target)
        except OSError as error:
            sock.close()
            log.warning("cannot open a socket to %s: %s", self.relay.target, error)
            stats.refused += 1
            return None
        session = _UdpSession(addr, sock, now)
        self.sessions[addr] = session
        stats.connections += 1
        stats.active += 1
        if not self.paused_bwd:
            self.loop.add_reader(sock.fileno(), self._on_reply, session)
        return session

    def _on_reply(self, session: _UdpSession) -> None:
        for _ in range(_READ_BATCH):
            try:
                data = session.sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:  # e.g. ICMP port unreachable from the target
                log.debug("udp reply to %s: %s", session.client, error)
                continue
            now = self.loop.time()
            session.last = now
            self.bwd.push(session, data, now)

    def sweep(self, now: float) -> None:
        """Close sessions idle for longer than ``udp_idle`` seconds."""
        idle = self.relay.options.udp_idle
        for addr, session in list(self.sessions.items()):
            if now - session.last > idle:
                self._close_session(addr, session)

    def _close_session(self, addr: Any, session: _UdpSession) -> None:
        del self.sessions[addr]
        session.closed = True
        if not self.paused_bwd:
            self.loop.remove_reader(session.sock.fileno())
        session.sock.close()
        self.relay.stats.active -= 1

    def close(self) -> None:
        self.fwd.clear()
        self.bwd.clear()
        if not self.paused_fwd:
            self.loop.remove_reader(self.sock.fileno())
        for addr, session in list(self.sessions.items()):
            self._close_session(addr, session)
        self.sock.close()


async def serve_udp(relay: Relay, stop: asyncio.Event, ready: Callable[[str], None]) -> None:
    """Relay UDP clients until ``stop`` is set; ``ready`` gets the listening endpoint.

    Raises
    ------
    ConfigError
        If the target cannot be resolved or the listening endpoint bound.
    """
    listen, target = relay.listen, relay.target
    loop = relay.loop
    try:
        infos = await loop.getaddrinfo(target.host, target.port, type=socket.SOCK_DGRAM)
    except OSError as error:
        raise endpoint_error("to", relay.options.to, "cannot resolve", error) from None
    family, _, _, _, target_addr = infos[0]
    try:
        linfos = await loop.getaddrinfo(listen.host, listen.port, type=socket.SOCK_DGRAM)
        lfamily, _, _, _, listen_addr = linfos[0]
        sock = socket.socket(lfamily, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.bind(listen_addr)
        except OSError:
            sock.close()
            raise
    except OSError as error:
        raise endpoint_error("listen", relay.options.listen, "cannot listen", error) from None
    udp = _UdpRelay(relay, sock, target_addr, family)
    relay.every_second.append(lambda: udp.sweep(loop.time()))
    sockname = sock.getsockname()
    ready(str(LinkEndpoint("udp", sockname[0], sockname[1])))
    try:
        await stop.wait()
    finally:
        udp.close()

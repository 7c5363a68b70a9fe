"""``fedlab bridge udp``'s socket layer (:mod:`federation.bridge.udp`) on real UDP sockets.

The bridge runs in this process on 127.0.0.1 with an in-process Zenoh session (peer mode,
no scouting, nothing dialled); a leader bridge, so the legacy agent's own clock is the
reference time and no other agent is needed. The test plays the legacy agent: one socket
at ``--peer`` answers the bridge's requests and sends its own; another socket on the same
host, another port, forges. Every wait is bounded; the bridge, its threads and every
socket are closed. The decisions themselves are tested in test_bridge_core.py.
"""

from __future__ import annotations

import logging
import socket
import threading
import time

import pytest
import zenoh

from federation.bridge.udp import UdpBridge, bind_udp
from federation.core import wire
from federation.core.paper import CLOCK_OFFSET
from schemas.bridge import UdpBridgeConfig
from schemas.config import validate

LEGACY_POSE = wire.Pose(1.25, -0.5, 0.3)


def udp_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", 0))
    except OSError:
        sock.close()
        raise
    return sock


class LegacyAgent:
    """The legacy agent's one socket (as tests/integration/legacy_agent.py's): answers the
    bridge's requests at once, and keeps the ``t1`` of the replies to its own."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.sock.settimeout(0.01)
        self.port = int(sock.getsockname()[1])
        self.answered: list[float] = []  # t1 of the bridge's replies to this agent's requests
        self.bridge_requests: list[float] = []  # t1 of the bridge's requests, unanswered ones too

    def request(self, bridge: tuple[str, int]) -> None:
        self.sock.sendto(wire.encode_request(time.monotonic() + CLOCK_OFFSET), bridge)

    def pump(self, seconds: float, answer: bool = True) -> None:
        """Read for ``seconds``; answer the bridge's requests if ``answer``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                data, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            if len(data) == wire.REQUEST_SIZE:
                t1 = wire.decode_request(data)
                self.bridge_requests.append(t1)
                if answer:
                    t2 = time.monotonic() + CLOCK_OFFSET
                    self.sock.sendto(wire.encode_reply(t1, t2, LEGACY_POSE), addr)
            elif len(data) == wire.REPLY_SIZE:
                self.answered.append(wire.decode_reply(data).t1)


def test_forged_requests_and_replies_are_dropped_and_requests_rate_limited(
    session: zenoh.Session, caplog: pytest.LogCaptureFixture
) -> None:
    """Through the socket: requests from another port of the legacy agent's host got
    replies (the followed pose, 8 bytes in and 64 out), as many as were sent; a reply
    from another port fed the legacy link."""
    caplog.set_level(logging.WARNING, logger="fedlab.bridge")
    with udp_socket() as own, udp_socket() as forger:
        legacy = LegacyAgent(own)
        forger.settimeout(0.3)
        sock = bind_udp(("127.0.0.1", 0))
        bridge_addr = ("127.0.0.1", int(sock.getsockname()[1]))
        settings = {
            "agent": "rome/legacy", "role": "leader",
            "listen": f"127.0.0.1:{bridge_addr[1]}", "peer": f"127.0.0.1:{legacy.port}",
            "request_port": legacy.port, "request_rate_limit": 5.0, "request_burst": 3,
        }  # fmt: skip
        try:
            bridge = UdpBridge(validate(UdpBridgeConfig, settings, "test"), session, sock)
        except BaseException:
            sock.close()
            raise
        stop = threading.Event()
        runner = threading.Thread(target=bridge.run, args=(stop,), daemon=True)
        try:
            bridge.start()
            runner.start()

            def counters() -> dict[str, int]:
                return bridge.status().counters

            # The legacy link up (its clock is reference time): its requests are answered.
            deadline = time.monotonic() + 15.0
            while not legacy.answered and time.monotonic() < deadline:
                legacy.request(bridge_addr)
                legacy.pump(0.25)
            assert legacy.answered, counters()
            legacy.pump(1.0)  # the bucket fills again: 3 tokens

            # Requests from another port of its host: no reply, counted, no token spent.
            for i in range(5):
                forger.sendto(wire.encode_request(float(i)), bridge_addr)
            legacy.pump(0.3)
            with pytest.raises(TimeoutError):
                forger.recvfrom(2048)
            assert counters().get("udp_requests_foreign_port") == 5, counters()

            # A reply to the bridge's request from another port: dropped, counted.
            seen = len(legacy.bridge_requests)
            deadline = time.monotonic() + 2.0
            while len(legacy.bridge_requests) == seen and time.monotonic() < deadline:
                legacy.pump(0.02, answer=False)
            assert len(legacy.bridge_requests) > seen
            t1 = legacy.bridge_requests[-1]
            forger.sendto(wire.encode_reply(t1, t1 + CLOCK_OFFSET, LEGACY_POSE), bridge_addr)
            legacy.pump(0.3)
            assert counters().get("udp_replies_foreign_port") == 1, counters()

            # A burst of 20 from the legacy agent's own port: 3 at once, then 5 a second.
            before, served = len(legacy.answered), counters().get("udp_requests_served", 0)
            limited = counters().get("udp_rate_limited", 0)
            for _ in range(20):
                legacy.request(bridge_addr)
            legacy.pump(1.0)
            answered = len(legacy.answered) - before
            after = counters()
            assert 1 <= answered <= 8, (answered, after)  # 3 once the bridge reads them at once
            assert after["udp_requests_served"] - served == answered
            assert after["udp_rate_limited"] - limited == 20 - answered
        finally:
            stop.set()
            runner.join(5.0)
            bridge.close()  # the socket too
        assert not runner.is_alive()
    log = caplog.text
    assert "rejected udp datagram (rate limited)" in log and "--request-rate-limit 5/s" in log
    assert "rejected udp datagram (foreign)" in log and f"--request-port {legacy.port}" in log

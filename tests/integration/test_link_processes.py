"""The link emulator live on loopback: ``fedlab link`` as a process between plain-socket
echo servers and clients on 127.0.0.1, and between Zenoh routers.

Bounded loops and socket timeouts; every process is stopped by pid and must exit 0
after SIGTERM or SIGINT.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import random
import re
import select
import signal
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest

from federation.fleet.launch import free_port, wait_for
from federation.link import parse_endpoint

pytestmark = pytest.mark.integration

LINK_CMD = [sys.executable, "-m", "federation", "link"]


def binomial_ok(k: int, n: int, p: float, sigmas: float = 5.0) -> bool:
    return abs(k - n * p) <= sigmas * math.sqrt(n * p * (1 - p)) + 1


def zenoh_conf(mode: str, listen: list[str], connect: list[str]) -> Any:
    """A router's or client's config on loopback; a client gives up after 5 s."""
    from federation.runtime.session import build_config
    from schemas.config import ZenohOptions

    extra = {"connect/timeout_ms": 5000, "connect/exit_on_failure": True}
    options = ZenohOptions(mode=mode, listen=listen, connect=connect)
    return build_config(options, default_mode=mode, extra=extra if mode == "client" else None)


# -- helpers ----------------------------------------------------------------
class LinkProcess:
    """``fedlab link ARGS`` as a child process; its stdout and stderr go to ``log``."""

    def __init__(self, args: list[str], log: Path):
        self.log = log
        self.stats_path = log.with_suffix(".json")
        self._out = log.open("wb")
        self.proc = subprocess.Popen(
            [*LINK_CMD, *args, "--stats-json", str(self.stats_path)],
            stdin=subprocess.DEVNULL,
            stdout=self._out,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        found: list[str] = []

        def ready() -> bool:
            match = re.search(r"listening on (\S+)", log.read_text())
            if match:
                found.append(match.group(1))
            return bool(match) or self.proc.poll() is not None

        wait_for(ready, timeout=15.0, interval=0.02)
        if not found:
            self.stop()
            pytest.fail(f"link did not start:\n{log.read_text()}")
        self.endpoint = parse_endpoint(found[0])

    @property
    def port(self) -> int:
        return self.endpoint.port

    def stop(self, sig: int = signal.SIGTERM, grace: float = 5.0) -> int:
        """Stop by pid; returns the exit code."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)
            try:
                self.proc.wait(grace)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(grace)
        self._out.close()
        return self.proc.returncode

    def stats(self) -> dict[str, Any]:
        data: dict[str, Any] = json.loads(self.stats_path.read_text())
        return data


@pytest.fixture
def start_link(tmp_path: Path) -> Iterator[Callable[..., LinkProcess]]:
    links: list[LinkProcess] = []

    def start(listen: str, to: str, flags: str = "") -> LinkProcess:
        args = ["--listen", listen, "--to", to, *flags.split()]
        link = LinkProcess(args, tmp_path / f"link{len(links)}.log")
        links.append(link)
        return link

    try:
        yield start
    finally:
        for link in links:
            code = link.stop()
            print(f"--- {link.log.name} (exit {code}) ---\n{link.log.read_text()[-3000:]}")


class TcpEcho:
    """A threaded TCP echo server on 127.0.0.1 (each connection echoed until EOF)."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port: int = self.server.getsockname()[1]
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self._accept, daemon=True)]

    def __enter__(self) -> TcpEcho:
        self.threads[0].start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        for thread in list(self.threads):
            thread.join(5.0)
        self.server.close()

    def _accept(self) -> None:
        self.server.settimeout(0.1)
        while not self.stop.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            thread = threading.Thread(target=self._echo, args=(conn,), daemon=True)
            self.threads.append(thread)
            thread.start()

    def _echo(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(10.0)
        with conn:
            while not self.stop.is_set():
                if not select.select([conn], [], [], 0.1)[0]:
                    continue
                data = conn.recv(1 << 16)
                if not data:
                    return
                conn.sendall(data)


class UdpEcho:
    """A threaded UDP echo server on 127.0.0.1."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port: int = self.sock.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> UdpEcho:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.sock.close()

    def _run(self) -> None:
        while not self.stop.is_set():
            if select.select([self.sock], [], [], 0.1)[0]:
                data, addr = self.sock.recvfrom(65536)
                self.sock.sendto(data, addr)


def round_trips(port: int, count: int, size: int = 64) -> list[float]:
    """Seconds per echo of ``size`` bytes through 127.0.0.1:``port``."""
    payload = b"x" * size
    times = []
    with socket.create_connection(("127.0.0.1", port), timeout=5.0) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(count):
            t0 = time.perf_counter()
            s.sendall(payload)
            got = 0
            while got < size:
                chunk = s.recv(size - got)
                assert chunk, "connection closed"
                got += len(chunk)
            times.append(time.perf_counter() - t0)
    return times


def quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


# -- live: TCP -------------------------------------------------------------------
@pytest.mark.timing
def test_tcp_round_trip_is_twice_the_one_way_delay(
    start_link: Callable[..., LinkProcess],
) -> None:
    with TcpEcho() as echo:
        link = start_link("tcp/127.0.0.1:0", f"tcp/127.0.0.1:{echo.port}", "--delay-ms 20")
        rtts = round_trips(link.port, 50)
        assert link.stop() == 0
    assert min(rtts) >= 0.040
    assert statistics.median(rtts) == pytest.approx(0.040, abs=0.003)
    stats = link.stats()
    assert stats["connections"] == 1 and stats["active"] == 0
    assert stats["forward"]["bytes"] == stats["backward"]["delivered_bytes"] == 50 * 64


@pytest.mark.timing
def test_tcp_overhead_at_zero_delay_is_well_under_a_millisecond(
    start_link: Callable[..., LinkProcess],
) -> None:
    with TcpEcho() as echo:
        link = start_link("tcp/127.0.0.1:0", f"tcp/127.0.0.1:{echo.port}")
        round_trips(echo.port, 50)  # warm up
        direct = round_trips(echo.port, 500)
        relayed = round_trips(link.port, 500)
        assert link.stop(signal.SIGINT) == 0
    added_p50 = statistics.median(relayed) - statistics.median(direct)
    added_p99 = quantile(relayed, 0.99) - quantile(direct, 0.99)
    print(f"link adds p50 {added_p50 * 1e3:.3f} ms, p99 {added_p99 * 1e3:.3f} ms per round trip")
    assert added_p50 < 0.001


def test_tcp_stream_arrives_whole_and_in_order_under_jitter_and_backpressure(
    start_link: Callable[..., LinkProcess],
) -> None:
    data = random.Random(42).randbytes(4 << 20)
    limit = 1 << 19
    with TcpEcho() as echo:
        link = start_link(
            "tcp/127.0.0.1:0",
            f"tcp/127.0.0.1:{echo.port}",
            "--delay-ms 5 --jitter-ms 3 --jitter-dist exp --backward-delay-ms 8 --seed 1"
            f" --max-queue-mib {limit / 2**20}",
        )
        received = bytearray()
        with socket.create_connection(("127.0.0.1", link.port), timeout=10.0) as s:

            def send() -> None:
                s.sendall(data)
                s.shutdown(socket.SHUT_WR)

            sender = threading.Thread(target=send, daemon=True)
            sender.start()
            deadline = time.monotonic() + 20.0
            while len(received) < len(data) and time.monotonic() < deadline:
                chunk = s.recv(1 << 16)
                if not chunk:
                    break
                received += chunk
            assert s.recv(1) == b""  # the close travels through too
            sender.join(10.0)
        assert link.stop() == 0
    assert len(received) == len(data)
    assert received == data
    stats = link.stats()
    for name in ("forward", "backward"):
        d = stats[name]
        assert d["bytes"] == d["delivered_bytes"] == len(data)
        assert d["lost"] == d["reordered"] == d["dropped"] == 0
        # Reading stops above the cap; one read (asyncio reads up to 256 KiB) may overshoot.
        assert 0 < d["max_queued_bytes"] <= limit + (1 << 18)
    assert stats["forward"]["pauses"] > 0


def test_unreachable_target_closes_the_client_and_duration_ends_the_run(
    start_link: Callable[..., LinkProcess],
) -> None:
    dead = free_port()
    link = start_link("tcp/127.0.0.1:0", f"tcp/127.0.0.1:{dead}", "--duration 2")
    with socket.create_connection(("127.0.0.1", link.port), timeout=5.0) as s:
        assert s.recv(1) == b""
    assert link.proc.wait(10.0) == 0
    stats = link.stats()
    assert stats["connections"] == 1 and stats["active"] == 0


# -- live: UDP -------------------------------------------------------------------
def test_udp_loss_and_reordering_at_the_configured_rates(
    start_link: Callable[..., LinkProcess],
) -> None:
    count, loss, reorder = 2000, 0.1, 0.05
    with UdpEcho() as echo:
        link = start_link(
            "udp/127.0.0.1:0",
            f"udp/127.0.0.1:{echo.port}",
            f"--delay-ms 1 --loss {loss} --reorder {reorder} --reorder-extra-ms 5 --seed 3",
        )
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("127.0.0.1", link.port))
            received: list[int] = []

            def receive() -> None:
                s.settimeout(1.0)
                deadline = time.monotonic() + 15.0
                while time.monotonic() < deadline:
                    try:
                        received.append(struct.unpack("!I", s.recv(64)[:4])[0])
                    except TimeoutError:
                        return

            receiver = threading.Thread(target=receive, daemon=True)
            receiver.start()
            for i in range(count):
                s.send(struct.pack("!I", i) + b"." * 32)
                if i % 50 == 49:
                    time.sleep(0.005)  # stay far below the socket buffers
                    # And at most about 150 on the way: a link (or this receiver) starved
                    # on a loaded host for a moment would have its socket's buffer
                    # overflow, and the kernel drop what was never read.
                    sent = i + 1
                    wait_for(
                        lambda: len(received) >= (1 - loss) ** 2 * sent - 150,  # noqa: B023
                        timeout=2.0, interval=0.002,
                    )  # fmt: skip
            receiver.join(20.0)
        assert link.stop() == 0
    stats = link.stats()
    fwd, bwd = stats["forward"], stats["backward"]
    assert fwd["datagrams"] == count
    assert binomial_ok(fwd["lost"], count, loss)
    assert bwd["datagrams"] == count - fwd["lost"]
    assert binomial_ok(bwd["lost"], bwd["datagrams"], loss)
    assert len(received) == bwd["delivered_datagrams"] == bwd["datagrams"] - bwd["lost"]
    assert binomial_ok(len(received), count, (1 - loss) ** 2)
    delivered = fwd["datagrams"] - fwd["lost"] + bwd["datagrams"] - bwd["lost"]
    assert binomial_ok(fwd["reordered"] + bwd["reordered"], delivered, reorder)
    assert any(a > b for a, b in itertools.pairwise(received))
    assert stats["connections"] == 1


# -- live: Zenoh through the link ------------------------------------------------
@pytest.mark.timing
def test_zenoh_routers_linked_through_the_emulator(
    start_link: Callable[..., LinkProcess],
) -> None:
    zenoh = pytest.importorskip("zenoh")

    delay = 0.030

    port_a, port_b = free_port(), free_port()
    latencies: list[float] = []
    with ExitStack() as stack:
        router_a = stack.enter_context(
            zenoh.open(zenoh_conf("router", [f"tcp/127.0.0.1:{port_a}"], []))
        )
        link = start_link("tcp/127.0.0.1:0", f"tcp/127.0.0.1:{port_a}", f"--delay-ms {delay * 1e3}")
        router_b = stack.enter_context(
            zenoh.open(zenoh_conf("router", [f"tcp/127.0.0.1:{port_b}"], [str(link.endpoint)]))
        )
        sub_session = stack.enter_context(
            zenoh.open(zenoh_conf("client", [], [f"tcp/127.0.0.1:{port_a}"]))
        )
        pub_session = stack.enter_context(
            zenoh.open(zenoh_conf("client", [], [f"tcp/127.0.0.1:{port_b}"]))
        )

        def on_sample(sample: Any) -> None:
            sent = struct.unpack("d", sample.payload.to_bytes())[0]
            latencies.append(time.monotonic() - sent)

        subscriber = sub_session.declare_subscriber("fedlab/test/link", on_sample)
        publisher = pub_session.declare_publisher("fedlab/test/link")
        try:
            deadline = time.monotonic() + 10.0
            while len(latencies) < 10 and time.monotonic() < deadline:
                publisher.put(struct.pack("d", time.monotonic()))
                time.sleep(0.05)
        finally:
            publisher.undeclare()
            subscriber.undeclare()
        assert router_a is not None and router_b is not None
    assert link.stop() == 0
    assert len(latencies) >= 10, "no samples crossed the link"
    assert min(latencies) >= delay
    assert statistics.median(latencies) < delay + 0.015
    assert link.stats()["forward"]["bytes"] > 0


@pytest.mark.timing
def test_zenoh_routers_linked_over_udp_through_a_jittery_link(
    start_link: Callable[..., LinkProcess],
) -> None:
    """Two routers on a UDP link through the emulator with jitter larger than the
    gaps between datagrams: declarations, samples, queries and replies all cross
    (a reordering relay lost the declarations, and with them everything)."""
    zenoh = pytest.importorskip("zenoh")
    tcp_a, udp_a, tcp_b = free_port(), free_port(), free_port()
    got: list[float] = []
    replies = 0
    with ExitStack() as stack:
        stack.enter_context(
            zenoh.open(
                zenoh_conf("router", [f"tcp/127.0.0.1:{tcp_a}", f"udp/127.0.0.1:{udp_a}"], [])
            )
        )
        link = start_link(
            "udp/127.0.0.1:0", f"udp/127.0.0.1:{udp_a}", "--delay-ms 20 --jitter-ms 2 --seed 2"
        )
        stack.enter_context(
            zenoh.open(zenoh_conf("router", [f"tcp/127.0.0.1:{tcp_b}"], [str(link.endpoint)]))
        )
        near = stack.enter_context(zenoh.open(zenoh_conf("client", [], [f"tcp/127.0.0.1:{tcp_a}"])))
        far = stack.enter_context(zenoh.open(zenoh_conf("client", [], [f"tcp/127.0.0.1:{tcp_b}"])))

        def on_sample(sample: Any) -> None:
            got.append(time.monotonic() - struct.unpack("d", sample.payload.to_bytes())[0])

        def on_query(query: Any) -> None:
            with query:
                query.reply(query.key_expr, b"pong")

        subscriber = near.declare_subscriber("fedlab/test/udp/pose", on_sample)
        queryable = near.declare_queryable("fedlab/test/udp/sync", on_query)
        publisher = far.declare_publisher("fedlab/test/udp/pose", express=True)
        try:
            deadline = time.monotonic() + 15.0
            while len(got) < 50 and time.monotonic() < deadline:  # routes come up first
                publisher.put(struct.pack("d", time.monotonic()))
                time.sleep(0.01)
            for _ in range(20):
                replies += sum(r.ok is not None for r in far.get("fedlab/test/udp/sync", timeout=2))
        finally:
            publisher.undeclare()
            queryable.undeclare()
            subscriber.undeclare()
    assert link.stop() == 0
    assert len(got) >= 50, "no samples crossed the UDP link"
    assert min(got) >= 0.020 and statistics.median(got) < 0.035
    assert replies == 20
    stats = link.stats()
    assert stats["forward"]["reordered"] == stats["backward"]["reordered"] == 0

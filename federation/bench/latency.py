"""``fedlab bench latency``: pose latency agent to agent across two lab routers,
beside baselines measured in the same run.

- ``fedlab pose``: a leader agent attached to router ``kiruna`` publishes pose at
  ``--rate``; a follower attached to router ``rome`` records each arrival. One-way
  latency = arrival minus sending, both on the host's monotonic clock (the
  leader's clock is mapped to it exactly through its status lines).
- ``bare zenoh``: a ping-pong through the same two routers with plain zenoh calls
  and the same transport settings (no fedlab code). One way is measured the same
  way as fedlab's (both ends read the host's monotonic clock); round trip / 2 is
  reported beside it.
- ``raw udp``: a socket ping-pong on loopback; one way = round trip / 2.
- ``sync turnaround``: the leader's time from reading ``t2`` to sending the reply
  (the reply's four-timestamp attachment), over the follower's exchanges.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from federation.fleet.launch import Fleet, free_port, wait_for
from federation.report.status import clock_line

__all__ = ["BASELINES", "PATHS", "bare_zenoh", "fedlab_pose", "raw_udp", "run"]

BASELINES = Path(__file__).with_name("baselines")


def _stats(values_s: list[float]) -> dict[str, float]:
    if not values_s:
        raise RuntimeError("no sample was measured")
    v = np.asarray(values_s) * 1e3
    return {
        "p50_ms": float(np.percentile(v, 50)),
        "p99_ms": float(np.percentile(v, 99)),
        "max_ms": float(v.max()),
        "n": len(values_s),
    }


def _client_config(endpoint: str) -> zenoh.Config:
    conf = zenoh.Config()
    for key, value in (
        ("mode", '"client"'),
        ("connect/endpoints", f'["{endpoint}"]'),
        ("scouting/multicast/enabled", "false"),
        # fedlab's transport defaults (federation/runtime/session.py).
        ("transport/unicast/lowlatency", "false"),
        ("transport/unicast/qos/enabled", "true"),
    ):
        conf.insert_json5(key, value)
    return conf


def _wait_ready(fleet: Fleet, name: str, timeout: float = 15.0) -> None:
    log = fleet.log_path(name)
    if not wait_for(lambda: log.exists() and "ready" in log.read_text(), timeout):
        raise RuntimeError(f"{name} did not start: {log.read_text() if log.exists() else ''}")


def bare_zenoh(
    fleet: Fleet, ping_at: str, pong_at: str, count: int, rate: float
) -> tuple[list[float], list[float]]:
    """(one-way, round trip / 2) latencies (s) of a plain zenoh ping-pong through both
    routers; one way from the pong's arrival stamp (same host, same monotonic clock)."""
    key = f"bench/{free_port()}"
    fleet.spawn(
        "zenoh-pong",
        [sys.executable, str(BASELINES / "zenoh_pong.py"), pong_at, key, str(count / rate + 30)],
    )
    _wait_ready(fleet, "zenoh-pong")
    sent: dict[int, int] = {}
    oneway: list[float] = []
    half_rtt: list[float] = []
    done = threading.Event()

    def on_pong(sample: zenoh.Sample) -> None:
        now = time.monotonic_ns()
        data = sample.payload.to_bytes()
        seq = int.from_bytes(data[:8], "little")
        arrived = int.from_bytes(data[-8:], "little")
        if seq in sent:
            start = sent.pop(seq)
            oneway.append((arrived - start) / 1e9)
            half_rtt.append((now - start) / 2e9)
            if len(oneway) >= count:
                done.set()

    with zenoh.open(_client_config(ping_at)) as session:
        sub = session.declare_subscriber(
            f"{key}/pong", zenoh.handlers.Callback(on_pong, indirect=False)
        )
        pub = session.declare_publisher(f"{key}/ping", express=True)
        # Until the route exists pings are lost: warm up with a bounded number.
        for seq in range(2**62, 2**62 + 200):
            if oneway:
                break
            sent[seq] = time.monotonic_ns()
            pub.put(seq.to_bytes(8, "little") + bytes(48))
            time.sleep(0.05)
        oneway.clear()
        half_rtt.clear()
        sent.clear()
        for seq in range(count):
            sent[seq] = time.monotonic_ns()
            pub.put(seq.to_bytes(8, "little") + bytes(48))  # 56 bytes, a pose sample's size
            time.sleep(1.0 / rate)
        done.wait(5.0)
        pub.undeclare()
        sub.undeclare()
    fleet.stop("zenoh-pong")
    return list(oneway), list(half_rtt)


def raw_udp(fleet: Fleet, count: int, rate: float) -> list[float]:
    """One-way latencies (s) of a plain UDP ping-pong on loopback."""
    port = free_port()
    fleet.spawn(
        "udp-pong",
        [
            sys.executable,
            str(BASELINES / "udp_pong.py"),
            "127.0.0.1",
            str(port),
            str(count / rate + 30),
        ],
    )
    _wait_ready(fleet, "udp-pong")
    oneway = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(1.0)
        for seq in range(count):
            payload = seq.to_bytes(8, "little") + bytes(48)
            start = time.perf_counter_ns()
            sock.sendto(payload, ("127.0.0.1", port))
            try:
                while sock.recvfrom(2048)[0] != payload:
                    pass
            except TimeoutError:
                continue
            oneway.append((time.perf_counter_ns() - start) / 2e9)
            time.sleep(1.0 / rate)
    fleet.stop("udp-pong")
    return oneway


def fedlab_pose(
    fleet: Fleet, kiruna: str, rome: str, seconds: float, rate: float, out: Path
) -> tuple[list[float], list[float]]:
    """(pose one-way latencies, sync turnarounds) in seconds, from real agents."""
    from federation.runtime.recorder import read_messages

    leader, follower = out / "leader.mcap", out / "follower.mcap"
    common = ["--duration", f"{seconds}", "--status-period", "0.5"]
    fleet.start(
        "leader",
        ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte", "-e", kiruna,
         "--pose-rate", f"{rate}", "--record", str(leader), *common],
    )  # fmt: skip
    fleet.start(
        "follower",
        ["agent", "--role", "follower", "--lab", "rome", "--name", "pinocchio", "-e", rome,
         "--follow", "kiruna/knatte", "--four-timestamps", "--record", str(follower), *common],
    )  # fmt: skip
    wait_for(lambda: not fleet.alive("follower") and not fleet.alive("leader"), seconds + 30, 0.5)
    a, b = clock_line(read_messages(leader, ["/status"])["/status"])
    got = read_messages(follower, ["/pose/received", "/sync/exchange"])
    latencies = [r["host_monotonic"] - (r["t"] - a) / b for r in got["/pose/received"]]
    turnarounds = [r["t2s"] - r["t2"] for r in got["/sync/exchange"] if r["t2s"] is not None]
    # The first second holds route set-up; score the steady state.
    return latencies[int(rate) :], turnarounds


PATHS = ("fedlab_pose", "bare_zenoh", "bare_zenoh_half_rtt", "raw_udp", "sync_turnaround")
"""The measured paths, in the order a table shows them; each a key of :func:`run`'s result."""


def run(seconds: float, rate: float, out: Path) -> dict[str, Any]:
    """Measure every path in :data:`PATHS` for ``seconds`` at ``rate`` samples per second.

    Returns each path's ``p50_ms``, ``p99_ms``, ``max_ms`` and ``n``, with the ratios
    ``ratio_p50_fedlab_over_bare`` and ``ratio_p50_bare_over_udp``.
    """
    out.mkdir(parents=True, exist_ok=True)
    kiruna, rome = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    count = int(seconds * rate)
    with Fleet(out / "logs") as fleet:
        fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
        fleet.start("router-rome", ["router", "--lab", "rome", "-l", rome, "-e", kiruna])
        pose, turnaround = fedlab_pose(fleet, kiruna, rome, seconds, rate, out)
        bare, bare_half_rtt = bare_zenoh(fleet, kiruna, rome, count, rate)
        udp = raw_udp(fleet, count, rate)
    result: dict[str, Any] = {
        "fedlab_pose": _stats(pose),
        "bare_zenoh": _stats(bare),
        "bare_zenoh_half_rtt": _stats(bare_half_rtt),
        "raw_udp": _stats(udp),
        "sync_turnaround": _stats(turnaround),
        "rate_hz": rate,
        "seconds": seconds,
    }
    result["ratio_p50_fedlab_over_bare"] = (
        result["fedlab_pose"]["p50_ms"] / result["bare_zenoh"]["p50_ms"]
    )
    result["ratio_p50_bare_over_udp"] = result["bare_zenoh"]["p50_ms"] / result["raw_udp"]["p50_ms"]
    return result

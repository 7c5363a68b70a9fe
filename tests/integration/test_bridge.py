"""``fedlab bridge udp``: a legacy agent speaking the paper's UDP packets joins a federation.

The legacy agent (tests/integration/legacy_agent.py) is plain sockets, no fedlab code, with its
clock 26.42 s off. Unit tests drive :class:`BridgeCore` with time passed in; the
integration test runs a router, a fedlab leader, the bridge and the legacy agent as
processes on loopback (bounded waits, every process stopped by pid, every Zenoh
session closed).
"""

from __future__ import annotations

import json
import math
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from federation.bridge.udp import BridgeConfig, BridgeCore, parse_address
from federation.core import wire
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.fleet.launch import Fleet, wait_for
from federation.report.status import last_status, read_status
from schemas.config import ConfigError

LEADER = "kiruna/knatte"
LEGACY = "rome/legacy"
LEGACY_OFFSET = 26.42  # the legacy agent's clock minus the host's monotonic clock
LEGACY_POSE = (1.25, -0.5, 0.3, 0.0, 0.0, 0.0)  # tests/integration/legacy_agent.py
LEGACY_AGENT = Path(__file__).with_name("legacy_agent.py")


# -- the protocol logic, time passed in --------------------------------------------------
def config(**overrides: Any) -> BridgeConfig:
    settings: dict[str, Any] = {
        "agent": AgentId("rome", "legacy"),
        "listen": ("127.0.0.1", 9000),
        "peer": ("127.0.0.1", 9001),
        "follow": AgentId("kiruna", "knatte"),
    }
    return BridgeConfig(**(settings | overrides))


def exchange(client_request: bytes, server_offset: float, t_send: float, rtt: float) -> bytes:
    """The reply a server whose clock is ``server_offset`` ahead sends to a request."""
    t1 = wire.decode_request(client_request)
    return wire.encode_reply(t1, t_send + rtt / 2 + server_offset, wire.Pose(2.0, 3.0, 0.1))


def sync_core(core: BridgeCore, legacy: float, reference: float, n: int = 20) -> float:
    """Feed ``n`` exchanges on both links (bridge clock starts at 100 s); returns now."""
    now = 100.0
    for _ in range(n):
        request = core.legacy_request(now)
        reply = wire.decode_request(request)
        data = wire.encode_reply(reply, now + 0.0005 + legacy, wire.Pose(*LEGACY_POSE))
        assert core.on_datagram(data, now + 0.001).pose is not None
        ref_request = core.reference_request(now)
        assert ref_request is not None
        assert core.on_reference_reply(exchange(ref_request, reference, now, 0.002), now + 0.002)
        now += 0.1
    return now


def test_legacy_request_before_reference_time_gets_no_reply() -> None:
    core = BridgeCore(config())
    outcome = core.on_datagram(wire.encode_request(5.0), 10.0)
    assert outcome.reply is None and outcome.rejected == "no reference time yet"
    assert core.counters["udp_requests_unsynced"] == 1


def test_replies_carry_reference_time_and_queries_legacy_time() -> None:
    core = BridgeCore(config())
    now = sync_core(core, legacy=26.42, reference=-3.0)
    core.on_followed_pose(wire.encode_pose(50.0, wire.Pose(0.5, 0.25, 0.7)))
    # The legacy agent's request: t2 on the leader's clock, the leader's pose.
    outcome = core.on_datagram(wire.encode_request(1234.5), now)
    assert outcome.reply is not None
    reply = wire.decode_reply(outcome.reply)
    assert reply.t1 == 1234.5
    assert reply.t2 == pytest.approx(now - 3.0, abs=1e-9)
    assert reply.pose == wire.Pose(0.5, 0.25, 0.7)
    # A federation query: t2 on the legacy agent's clock, the legacy agent's pose.
    answer = core.on_sync_query(wire.encode_request(7.0), now)
    assert answer is not None
    reply = wire.decode_reply(answer[0])
    assert reply.t1 == 7.0
    assert reply.t2 == pytest.approx(now + 26.42, abs=1e-9)
    assert reply.pose == wire.Pose(*LEGACY_POSE)
    # Status is on the legacy agent's clock; the leader's offset relative to it.
    status = core.status(now, host=500.0)
    assert status.t_exec == pytest.approx(now + 26.42, abs=1e-9)
    assert status.peers[LEADER].offset == pytest.approx(-3.0 - 26.42, abs=1e-9)
    assert status.t_sim == pytest.approx(now - 3.0, abs=1e-9)
    extra = status.model_dump()
    assert extra["clock"] == "legacy" and extra["legacy"]["offset"] == pytest.approx(26.42)
    assert status.role == "follower" and status.reference == LEADER
    assert status.pose == list(LEGACY_POSE)


def test_leader_bridge_serves_the_legacy_clock_as_reference_time() -> None:
    core = BridgeCore(config(role="leader", follow=None))
    assert core.reference_request(0.0) is None
    now = 100.0
    for _ in range(5):
        t1 = wire.decode_request(core.legacy_request(now))
        core.on_datagram(wire.encode_reply(t1, now + 0.0005 + 7.0, wire.Pose()), now + 0.001)
        now += 0.1
    outcome = core.on_datagram(wire.encode_request(1.0), now)
    assert outcome.reply is not None
    assert wire.decode_reply(outcome.reply).t2 == pytest.approx(now + 7.0, abs=1e-9)
    assert core.status(now, 0.0).reference == LEGACY


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x00" * 7, "got 7"),
        (b"\x00" * 65, "got 65"),
        (b"", "got 0"),
        (struct.pack("<d", math.nan), "not a finite number"),
        (struct.pack("<d", math.inf), "not a finite number"),
        (struct.pack("<8d", 1.0, math.nan, 0, 0, 0, 0, 0, 0), "malformed"),
    ],
)
def test_malformed_datagrams_are_dropped_and_counted(data: bytes, reason: str) -> None:
    core = BridgeCore(config())
    sync_core(core, 26.42, -3.0, n=3)
    outcome = core.on_datagram(data, 200.0)
    assert outcome.reply is None and outcome.pose is None
    assert outcome.rejected is not None and reason in outcome.rejected
    assert core.counters["udp_malformed"] == 1


def test_malformed_federation_query_raises_decode_error_and_is_counted() -> None:
    core = BridgeCore(config())
    with pytest.raises(wire.DecodeError):
        core.on_sync_query(b"\x00" * 7, 1.0)
    assert core.counters["sync_requests_malformed"] == 1


def test_legacy_agent_silent_is_lost_and_its_clock_forgotten() -> None:
    core = BridgeCore(config(legacy_timeout=2.0))
    assert core.on_sync_query(wire.encode_request(1.0), 50.0) is None  # never seen
    now = sync_core(core, 26.42, -3.0)
    assert core.check_legacy(now)
    assert core.on_sync_query(wire.encode_request(1.0), now) is not None
    assert not core.check_legacy(now + 2.5)
    assert core.on_sync_query(wire.encode_request(1.0), now + 2.5) is None
    assert core.legacy_offset(now + 2.5) is None
    assert core.counters["legacy_lost"] == 1


def test_parse_address() -> None:
    assert parse_address("127.0.0.1:9000", "--peer") == ("127.0.0.1", 9000)
    assert parse_address("[::1]:9000", "--peer") == ("::1", 9000)
    for bad in ("9000", "host:", "host:x", ":9000", "host:70000"):
        with pytest.raises(ConfigError, match="HOST:PORT"):
            parse_address(bad, "--peer")


def test_bridge_config_refuses_bad_values() -> None:
    with pytest.raises(ConfigError, match="sync-period"):
        config(sync_period=0.0)
    with pytest.raises(ConfigError, match="cannot follow itself"):
        config(follow=AgentId("rome", "legacy"))


def test_sync_client_accepts_the_bridges_legacy_replies_only_once() -> None:
    # The bridge never answers its own replies: a duplicate is rejected, not re-published.
    core = BridgeCore(config())
    t1 = wire.decode_request(core.legacy_request(10.0))
    data = wire.encode_reply(t1, 36.42, wire.Pose())
    assert core.on_datagram(data, 10.001).pose is not None
    again = core.on_datagram(data, 10.002)
    assert again.pose is None and again.rejected == "sync reply (duplicate)"
    assert isinstance(core.legacy.client, SyncClient)


# -- real processes ------------------------------------------------------------------
def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def start_bridge(fleet: Fleet, args: list[str]) -> None:
    fleet.start("bridge", ["bridge", "udp", *args])


def legacy_lines(fleet: Fleet) -> list[dict[str, Any]]:
    """The legacy agent's JSON lines from its log (other lines skipped)."""
    return read_status(fleet.log_path("legacy"))


def legacy_samples(fleet: Fleet) -> int:
    lines = legacy_lines(fleet)
    return int(lines[-1]["samples"]) if lines else 0


class PoseTap:
    """A Zenoh subscriber on the legacy agent's pose key; the payloads it received."""

    def __init__(self, endpoint: str, key: str):
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.payloads: list[bytes] = []
        self._lock = threading.Lock()
        self.session = zenoh.open(conf)
        self.sub = self.session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._lock:
            if len(self.payloads) < 10_000:
                self.payloads.append(sample.payload.to_bytes())

    def received(self) -> list[bytes]:
        with self._lock:
            return list(self.payloads)

    def close(self) -> None:
        self.sub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


@pytest.mark.integration
def test_legacy_udp_agent_syncs_with_a_fedlab_leader_through_the_bridge(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna = endpoint()
    fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
    leader_status = tmp_path / "leader.jsonl"
    fleet.start(
        "kiruna-knatte",
        # The leader queries the bridged agent every 0.1 s, not once a second.
        ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte", "-e", kiruna,
         "--status-json", str(leader_status), "--status-period", "0.5",
         "--sync-others-period", "0.1"],
    )  # fmt: skip
    bridge_port, legacy_port = free_udp_port(), free_udp_port()
    fleet.spawn(
        "legacy",
        [sys.executable, str(LEGACY_AGENT), str(legacy_port), f"127.0.0.1:{bridge_port}",
         str(LEGACY_OFFSET), "60"],
    )  # fmt: skip
    bridge_status = tmp_path / "bridge.jsonl"
    # No --follow: the bridge finds the leader by its status.
    start_bridge(
        fleet,
        ["--as", LEGACY, "--listen", f"127.0.0.1:{bridge_port}",
         "--peer", f"127.0.0.1:{legacy_port}", "-e", kiruna,
         "--status-json", str(bridge_status), "--status-period", "0.5",
         "--legacy-timeout", "1.0"],
    )  # fmt: skip
    # The leader writes status once its session is up: then the router is too.
    assert wait_for(lambda: last_status(leader_status) is not None, timeout=10)
    tap = PoseTap(kiruna, f"fedlab/default/{LEGACY}/pose")
    try:
        assert wait_for(lambda: legacy_samples(fleet) >= 50, timeout=20), legacy_lines(fleet)[-3:]

        def leader_view() -> dict[str, Any] | None:
            line = last_status(leader_status)
            return None if line is None else line["peers"].get(LEGACY)

        assert wait_for(lambda: (leader_view() or {}).get("samples", 0) >= 20, timeout=10)

        # The legacy agent's own estimate of the leader's clock (Eq. 4, median of 50).
        leader_line = read_status(leader_status)[-1]
        leader_clock = leader_line["t_exec"] - leader_line["host_monotonic"]  # minus host
        truth = leader_clock - LEGACY_OFFSET  # leader's clock minus the legacy agent's
        legacy = legacy_lines(fleet)[-1]
        error_legacy = legacy["offset"] - truth
        assert abs(error_legacy) < 0.002, (legacy, truth)
        assert legacy["pose"] is not None and len(legacy["pose"]) == 6  # the leader's pose
        # The bridge's requests leave from its --listen socket: the flow a firewall opens.
        assert legacy["request_sources"] == [f"127.0.0.1:{bridge_port}"]
        assert legacy["served"] > 0

        # The leader synced with the legacy agent through the bridge.
        view = leader_view()
        assert view is not None and view["alive"] and view["samples"] > 0
        error_leader = view["offset"] + truth  # legacy minus leader
        assert abs(error_leader) < 0.002, (view, truth)

        # The federation sees its pose: 56-byte samples on the legacy agent's clock.
        payloads = tap.received()
        assert len(payloads) >= 10
        assert {len(p) for p in payloads} == {56}
        sample = wire.decode_pose(payloads[-1])
        assert sample.pose == wire.Pose(*LEGACY_POSE)
        assert abs(sample.t - (time.monotonic() + LEGACY_OFFSET)) < 1.0

        # The bridge's status: on the legacy agent's clock, the leader as reference.
        status = last_status(bridge_status)
        assert status is not None
        assert status["agent"] == LEGACY and status["role"] == "follower"
        assert status["reference"] == LEADER and status["clock"] == "legacy"
        assert status["t_exec"] - status["host_monotonic"] == pytest.approx(
            LEGACY_OFFSET, abs=0.002
        )
        assert status["legacy"]["samples"] > 0 and status["legacy"]["alive"]

        # Malformed datagrams are dropped and counted; nothing stops the bridge.
        bad = [
            b"\x00" * 7,
            struct.pack("<d", math.nan),
            struct.pack("<8d", 1.0, math.nan, 0, 0, 0, 0, 0, 0),
            b"\x01" * 65,
        ]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for payload in bad:
                s.sendto(payload, ("127.0.0.1", bridge_port))

        def counted() -> bool:
            line = last_status(bridge_status)
            return line is not None and line["counters"].get("udp_malformed", 0) == len(bad)

        assert wait_for(counted, timeout=5), last_status(bridge_status)
        before = legacy_samples(fleet)
        assert wait_for(lambda: legacy_samples(fleet) >= before + 10, timeout=5)
        assert fleet.alive("bridge")
        log = fleet.log_path("bridge").read_text()
        assert "rejected udp datagram (malformed)" in log and "got 7" in log

        # The legacy agent goes silent: after --legacy-timeout its token goes, the bridge stays.
        assert fleet.stop("legacy") == 0
        assert wait_for(lambda: not (leader_view() or {"alive": True})["alive"], timeout=5)

        def bridge_saw_it_go() -> bool:
            line = last_status(bridge_status)
            return line is not None and not line["legacy"]["alive"]

        assert wait_for(bridge_saw_it_go, timeout=5), last_status(bridge_status)
        status = last_status(bridge_status)
        assert status is not None
        assert status["clock"] == "bridge" and status["counters"]["legacy_lost"] == 1
        assert fleet.alive("bridge")

        # It comes back with another clock: the federation syncs with the new one.
        fleet.spawn(
            "legacy-again",
            [sys.executable, str(LEGACY_AGENT), str(legacy_port), f"127.0.0.1:{bridge_port}",
             "-5.0", "60"],
        )  # fmt: skip

        def resynced() -> bool:
            view, line = leader_view(), last_status(leader_status)
            if view is None or line is None or not view["alive"] or view["offset"] is None:
                return False
            return abs(view["offset"] - (-5.0 - (line["t_exec"] - line["host_monotonic"]))) < 0.002

        assert wait_for(resynced, timeout=10), leader_view()

        # SIGTERM: clean exit; the token goes first, so the leader sees the agent leave.
        assert fleet.stop("bridge") == 0
        assert wait_for(lambda: not (leader_view() or {"alive": True})["alive"], timeout=5)
        print(
            f"legacy estimate error {error_legacy * 1e3:+.3f} ms, "
            f"leader estimate error {error_leader * 1e3:+.3f} ms, "
            f"legacy delay {legacy['delay'] * 1e3:.3f} ms, pose samples {len(payloads)}"
        )
    finally:
        tap.close()

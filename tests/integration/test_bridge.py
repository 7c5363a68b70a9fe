"""``fedlab bridge udp``: a legacy agent speaking the paper's UDP packets joins a federation.

The legacy agent (tests/integration/legacy_agent.py) is plain sockets, no fedlab code, with its
clock 26.42 s off (the paper's offset). A router, a fedlab leader, the bridge and the legacy
agent run as processes on loopback (the ``labs`` fixture: bounded waits, every process
stopped by pid, every Zenoh session closed). The protocol logic, time passed in, is tested in
tests/unit/bridge/test_bridge_core.py.
"""

from __future__ import annotations

import math
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from loopback import FLOAT_SLACK, LEADER, Agent, Labs, Tap, answer_sync, client_config, offset_error

from federation.core import wire
from federation.core.paper import CLOCK_OFFSET
from federation.fleet.launch import Fleet, free_port, wait_for
from federation.report.status import read_status

LEGACY = "rome/legacy"
LEGACY_OFFSET = CLOCK_OFFSET  # the legacy agent's clock minus the host's monotonic clock
LEGACY_POSE = (1.25, -0.5, 0.3, 0.0, 0.0, 0.0)  # tests/integration/legacy_agent.py
LEGACY_AGENT = Path(__file__).with_name("legacy_agent.py")


def start_bridge(labs: Labs, *args: str) -> Agent:
    """``fedlab bridge udp ARGS`` as the legacy agent, its status lines in ``bridge.jsonl``."""
    status = labs.tmp / "bridge.jsonl"
    argv = ["bridge", "udp", "--as", LEGACY, *args, "--status-json", str(status)]
    bridge = Agent(labs.fleet, "bridge", argv, who=LEGACY, status=status)
    bridge.start()
    return bridge


def start_legacy(
    fleet: Fleet, name: str, legacy_port: int, bridge_port: int, offset: float
) -> None:
    """The legacy agent on ``legacy_port``, its clock ``offset`` s off, for 60 s."""
    fleet.spawn(
        name,
        [sys.executable, str(LEGACY_AGENT), str(legacy_port), f"127.0.0.1:{bridge_port}",
         str(offset), "60"],
    )  # fmt: skip


def legacy_lines(fleet: Fleet) -> list[dict[str, Any]]:
    """The legacy agent's JSON lines from its log (other lines skipped)."""
    return read_status(fleet.log_path("legacy"))


def legacy_samples(fleet: Fleet) -> int:
    lines = legacy_lines(fleet)
    return int(lines[-1]["samples"]) if lines else 0


def legacy_samples_since(fleet: Fleet, instant: float, timeout: float = 5.0) -> int:
    """The legacy agent's replies as of its first line printed after host monotonic
    ``instant``: its lines are 1 s apart, so the last one printed may predate a reply it
    had already received (bounded wait)."""

    def printed() -> list[dict[str, Any]]:
        return [line for line in legacy_lines(fleet) if line["host"] > instant]

    assert wait_for(printed, timeout), f"no line of the legacy agent after {instant}"
    return int(printed()[0]["samples"])


def more_held(
    bridge: Agent, counters: tuple[str, ...], since: dict[str, Any], n: int
) -> dict[str, Any]:
    """Wait until ``counters`` (summed) in the bridge's status lines have grown by ``n``
    since its line ``since``: ``n`` more requests of the legacy agent came in and got no
    reply (bounded: they come at 10 Hz)."""

    def total(line: dict[str, Any]) -> int:
        return sum(int(line["counters"].get(name, 0)) for name in counters)

    start = total(since)
    return bridge.until(
        lambda line: total(line) >= start + n, timeout=n * 0.1 + 10, what=f"{n} more {counters}"
    )


def gone(line: dict[str, Any]) -> bool:
    """The leader's status line shows the legacy agent gone (not yet seen: not gone)."""
    return not line["peers"].get(LEGACY, {"alive": True})["alive"]


@pytest.mark.integration
def test_legacy_udp_agent_syncs_with_a_fedlab_leader_through_the_bridge(
    labs: Labs, fleet: Fleet
) -> None:
    router = labs.router("kiruna")
    # The leader queries the bridged agent every 0.1 s, not once a second.
    leader = labs.leader(router, "--sync-others-period", "0.1")
    bridge_port, legacy_port = free_port(), free_port()
    start_legacy(fleet, "legacy", legacy_port, bridge_port, LEGACY_OFFSET)
    # No --follow: the bridge finds the leader by its status.
    bridge = start_bridge(
        labs,
        "--listen", f"127.0.0.1:{bridge_port}", "--peer", f"127.0.0.1:{legacy_port}",
        "-e", router.endpoint, "--status-period", "0.5", "--legacy-timeout", "1.0",
    )  # fmt: skip
    # The leader writes status once its session is up: then the router is too.
    leader.wait_status(timeout=10)
    tap = Tap(router.endpoint, f"fedlab/default/{LEGACY}/pose", bytes)  # raw payloads
    try:
        assert wait_for(lambda: legacy_samples(fleet) >= 50, timeout=20), legacy_lines(fleet)[-3:]
        leader.wait_samples(LEGACY, 20, timeout=10)

        # The legacy agent's own estimate of the leader's clock (Eq. 4, median of 50).
        leader_line = leader.latest()
        leader_clock = leader_line["t_exec"] - leader_line["host_monotonic"]  # minus host
        truth = leader_clock - LEGACY_OFFSET  # leader's clock minus the legacy agent's
        legacy = legacy_lines(fleet)[-1]
        error_legacy = legacy["offset"] - truth
        # Its replies' t2 is the bridge's estimate of the leader's clock: the legacy
        # agent's error is at most its own exchanges' (delay_max) plus the bridge's.
        hop = bridge.latest()["peers"][LEADER]
        stated = legacy["delay_max"] + hop["delay"] + hop["bound"]
        assert abs(error_legacy) <= stated + FLOAT_SLACK, (legacy, hop, truth)
        assert legacy["pose"] is not None and len(legacy["pose"]) == 6  # the leader's pose
        # The bridge's requests leave from its --listen socket: the flow a firewall opens.
        assert legacy["request_sources"] == [f"127.0.0.1:{bridge_port}"]
        assert legacy["served"] > 0

        # The leader synced with the legacy agent through the bridge.
        view = leader.peer(LEGACY)
        assert view is not None and view["alive"] and view["samples"] > 0
        error_leader = offset_error(view, -truth)  # legacy minus leader

        # The federation sees its pose: 56-byte samples on the legacy agent's clock.
        payloads = tap.received()
        assert len(payloads) >= 10
        assert {len(p) for p in payloads} == {56}
        sample = wire.decode_pose(payloads[-1])
        assert sample.pose == wire.Pose(*LEGACY_POSE)
        assert abs(sample.t - (time.monotonic() + LEGACY_OFFSET)) < 1.0

        # The bridge's status: on the legacy agent's clock, the leader as reference.
        status = bridge.latest()
        assert status["agent"] == LEGACY and status["role"] == "follower"
        assert status["reference"] == LEADER and status["clock"] == "legacy"
        link = status["legacy"]  # the bridge's estimate of the legacy agent's clock
        error_clock = status["t_exec"] - status["host_monotonic"] - LEGACY_OFFSET
        assert abs(error_clock) <= link["delay"] + link["bound"] + FLOAT_SLACK, (link, error_clock)
        assert status["legacy"]["samples"] > 0 and status["legacy"]["alive"]

        # Malformed datagrams are dropped and counted; nothing stops the bridge. A reply
        # from a port other than --peer's is not read at all.
        bad = [b"\x00" * 7, struct.pack("<d", math.nan), b"\x01" * 65]
        reply = struct.pack("<8d", 1.0, math.nan, 0, 0, 0, 0, 0, 0)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for payload in [*bad, reply]:
                s.sendto(payload, ("127.0.0.1", bridge_port))
        bridge.until(
            lambda line: (
                line["counters"].get("udp_malformed", 0) == len(bad)
                and line["counters"].get("udp_replies_foreign_port", 0) == 1
            ),
            timeout=5,
            what=f"{len(bad)} malformed datagrams and a reply from another port counted",
        )
        before = legacy_samples(fleet)
        assert wait_for(lambda: legacy_samples(fleet) >= before + 10, timeout=5)
        assert bridge.alive()
        log = bridge.log()
        assert "rejected udp datagram (malformed)" in log and "got 7" in log

        # The legacy agent goes silent: after --legacy-timeout its token goes, the bridge stays.
        assert fleet.stop("legacy") == 0
        leader.until(gone, timeout=5, what=f"{LEGACY} gone")
        status = bridge.until(
            lambda line: not line["legacy"]["alive"], timeout=5, what="the legacy agent gone"
        )
        assert status["clock"] == "bridge" and status["counters"]["legacy_lost"] == 1
        assert bridge.alive()

        # It comes back with another clock: the federation syncs with the new one.
        start_legacy(fleet, "legacy-again", legacy_port, bridge_port, -5.0)

        def resynced(line: dict[str, Any]) -> bool:
            view = line["peers"].get(LEGACY)
            if view is None or not view["alive"] or view["offset"] is None:
                return False
            truth = -5.0 - (line["t_exec"] - line["host_monotonic"])
            return bool(abs(view["offset"] - truth) <= view["delay"] + view["bound"] + FLOAT_SLACK)

        leader.until(resynced, timeout=10, what=f"the new clock of {LEGACY}")

        # SIGTERM: clean exit; the token goes first, so the leader sees the agent leave.
        # A stop still under way after 4 s writes the threads' stacks into the log.
        assert bridge.stop() == 0, bridge.log()[-4000:]
        leader.until(gone, timeout=5, what=f"{LEGACY} gone")
        print(
            f"legacy estimate error {error_legacy * 1e3:+.3f} ms, "
            f"leader estimate error {error_leader * 1e3:+.3f} ms, "
            f"legacy delay {legacy['delay'] * 1e3:.3f} ms, pose samples {len(payloads)}"
        )
    finally:
        tap.close()


@pytest.mark.integration
def test_a_bridge_refuses_a_name_already_in_the_federation(labs: Labs, fleet: Fleet) -> None:
    router = labs.router("kiruna")
    leader = labs.leader(router)
    leader.wait_status(timeout=10)
    bridge_port, legacy_port = free_port(), free_port()
    argv = [
        "bridge", "udp", "--as", LEADER, "--listen", f"127.0.0.1:{bridge_port}",
        "--peer", f"127.0.0.1:{legacy_port}", "-e", router.endpoint,
    ]  # fmt: skip
    fleet.start("bridge", argv)
    assert wait_for(lambda: not fleet.alive("bridge"), timeout=20), "the bridge kept running"
    assert fleet.stop("bridge") == 2
    log = fleet.log_path("bridge").read_text()
    assert f"agent {LEADER} is already in federation default" in log, log
    assert leader.alive() and leader.latest()["hold"] is None


@pytest.mark.integration
def test_a_second_process_answering_for_the_legacy_agent_stops_the_bridge_for_good(
    labs: Labs, fleet: Fleet
) -> None:
    """The race the start-up check cannot see: another session answers the legacy agent's
    sync key just after the bridge declared the name. The bridge's look 2 s later hears
    it: it stops speaking for the legacy agent (no more replies to it, no pose from it,
    no token), says why, and stays so once the other has gone."""
    router = labs.router("kiruna")
    leader = labs.leader(router)
    key = f"fedlab/default/{LEGACY}"
    conf = client_config(router.endpoint)
    conf.insert_json5("connect/timeout_ms", "10000")
    racer = zenoh.open(conf)
    declared: list[Any] = []
    up = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            up.set()

    watch = racer.liveliness().declare_subscriber(key, on_token)
    try:
        bridge_port, legacy_port = free_port(), free_port()
        start_legacy(fleet, "legacy", legacy_port, bridge_port, LEGACY_OFFSET)
        bridge = start_bridge(
            labs,
            "--listen", f"127.0.0.1:{bridge_port}", "--peer", f"127.0.0.1:{legacy_port}",
            "--follow", LEADER, "-e", router.endpoint, "--status-period", "0.5",
        )  # fmt: skip
        assert up.wait(30), "the bridge never declared the legacy agent's name"
        declared.append(racer.declare_queryable(f"{key}/sync", answer_sync))
        held = bridge.until(lambda line: line.get("hold") == "name_taken", 10, "name hold")
        assert held["counters"]["name_taken_holds"] == 1, held["counters"]
        assert "2 processes answer for rome/legacy in federation default" in bridge.log()
        # Held: the legacy agent gets no more replies, and the token went.
        leader.until(gone, timeout=5, what=f"{LEGACY} gone")
        # Held since before the token went; a reply already in flight lands within 0.2 s.
        before = legacy_samples_since(fleet, time.monotonic() + 0.2)
        while declared:  # the other one stops: the bridge stays held
            declared.pop().undeclare()
        # 20 more of the legacy agent's requests (2 s at 10 Hz) come in, each held.
        more_held(bridge, ("udp_held_for_name",), since=bridge.latest(), n=20)
        assert legacy_samples_since(fleet, time.monotonic()) == before
        line = bridge.latest()
        assert line["hold"] == "name_taken" and line["counters"]["name_taken_holds"] == 1
        assert line["counters"]["udp_held_for_name"] > 0
        assert bridge.alive()
    finally:
        for entity in declared:
            entity.undeclare()
        watch.undeclare()  # type: ignore[no-untyped-call]
        racer.close()  # type: ignore[no-untyped-call]


@pytest.mark.integration
def test_the_legacy_agent_gets_no_reply_while_aborted_or_without_its_leader(
    labs: Labs, fleet: Fleet
) -> None:
    """What fails closed for a legacy agent is no reply (its own design holds on a lost
    link): after ctl abort until ctl reset, and once the leader it follows is gone. The
    bridge had answered both with the last pose it held, for ever. With --request-port,
    none either to a request from another port of its host: any process there had got
    the leader's pose, 64 bytes for 8."""
    import subprocess

    router = labs.router("kiruna")
    leader = labs.leader(router)
    bridge_port, legacy_port = free_port(), free_port()
    start_legacy(fleet, "legacy", legacy_port, bridge_port, LEGACY_OFFSET)
    bridge = start_bridge(
        labs, "--listen", f"127.0.0.1:{bridge_port}", "--peer", f"127.0.0.1:{legacy_port}",
        "--request-port", str(legacy_port),  # its one socket: requests and replies
        "--follow", LEADER, "-e", router.endpoint, "--status-period", "0.5",
    )  # fmt: skip
    bridge.wait_status(timeout=20)  # its socket is bound: forged requests reach it

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as forger:
        forger.bind(("127.0.0.1", 0))
        forger.settimeout(1.0)  # no reply within 1 s: none comes
        for t1 in (1.0, 2.0, 3.0):
            forger.sendto(wire.encode_request(t1), ("127.0.0.1", bridge_port))
        with pytest.raises(TimeoutError):
            forger.recvfrom(2048)
    bridge.until(
        lambda s: s["counters"].get("udp_requests_foreign_port", 0) == 3, 5, "3 forged requests"
    )
    leader.wait_status(timeout=10)
    assert wait_for(lambda: legacy_samples(fleet) >= 20, timeout=20), legacy_lines(fleet)[-3:]

    def ctl(command: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "federation", "ctl", command, "-e", router.endpoint],
            capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
        )  # fmt: skip

    def unanswered(counters: tuple[str, ...]) -> None:
        """The bridge holding (its ``counters`` growing): the legacy agent's replies as of
        its first line once a reply in flight has landed (0.2 s) are all it has after
        10 more of its requests (1 s at 10 Hz) got none."""
        before = legacy_samples_since(fleet, time.monotonic() + 0.2)
        more_held(bridge, counters, since=bridge.latest(), n=10)
        assert legacy_samples_since(fleet, time.monotonic()) == before, legacy_lines(fleet)[-3:]

    aborted = ctl("abort")
    assert aborted.returncode == 0, aborted.stdout + aborted.stderr  # the bridge confirmed
    bridge.until(lambda s: s["mode"] == "aborted" and s["hold"] == "aborted", 5, "aborted")
    unanswered(("udp_requests_held",))
    reset = ctl("reset")
    assert reset.returncode == 0, reset.stdout + reset.stderr
    replied = legacy_samples(fleet)
    assert wait_for(lambda: legacy_samples(fleet) > replied + 5, timeout=10), legacy_lines(fleet)

    assert leader.stop() == 0  # the pose it follows stops
    stale_or_gone = ("udp_requests_stale", "udp_requests_reference_gone")
    more_held(bridge, stale_or_gone, since=bridge.latest(), n=1)  # it holds from here on
    unanswered(stale_or_gone)
    counters = bridge.latest()["counters"]
    assert counters["udp_requests_held"] > 0
    assert (
        counters.get("udp_requests_stale", 0) + counters.get("udp_requests_reference_gone", 0) > 0
    )
    assert bridge.alive()

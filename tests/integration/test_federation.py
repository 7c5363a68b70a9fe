"""Integration: real routers and agents as separate processes on loopback.

Every wait is bounded; every process is stopped by pid (the ``fleet`` fixture);
every Zenoh session opened here is closed.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from federation.fleet.launch import Fleet, wait_for
from federation.report.status import last_status, read_status, true_offset

pytestmark = pytest.mark.integration

LEADER = "kiruna/knatte"
FOLLOWER = "rome/pinocchio"


def start_router(fleet: Fleet, lab: str, listen: str, connect: str | None = None) -> None:
    args = ["router", "--lab", lab, "-l", listen]
    if connect:
        args += ["-e", connect]
    fleet.start(f"router-{lab}", args)


def start_agent(fleet: Fleet, tmp: Path, role: str, agent: str, endpoint: str, *extra: str) -> Path:
    lab, name = agent.split("/")
    status = tmp / f"{lab}-{name}.jsonl"
    args = ["agent", "--role", role, "--lab", lab, "--name", name, "-e", endpoint]
    args += ["--status-json", str(status), "--status-period", "0.5", *extra]
    fleet.start(f"{lab}-{name}", args)
    return status


def peer_view(status: Path, peer: str) -> dict[str, Any] | None:
    line = last_status(status)
    return None if line is None else line["peers"].get(peer)


def samples(status: Path, peer: str) -> int:
    view = peer_view(status, peer)
    return 0 if view is None else int(view["samples"])


def two_labs(fleet: Fleet, endpoint: Callable[[], str]) -> tuple[str, str]:
    kiruna, rome = endpoint(), endpoint()
    start_router(fleet, "kiruna", kiruna)
    start_router(fleet, "rome", rome, connect=kiruna)
    return kiruna, rome


def test_follower_estimates_leader_clock_across_two_labs(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna, rome = two_labs(fleet, endpoint)
    leader = start_agent(fleet, tmp_path, "leader", LEADER, kiruna)
    follower = start_agent(
        fleet, tmp_path, "follower", FOLLOWER, rome, "--follow", LEADER, "--clock-offset", "26.42"
    )
    assert wait_for(lambda: samples(follower, LEADER) >= 20, timeout=15), "no sync within 15 s"

    view = peer_view(follower, LEADER)
    assert view is not None
    truth = true_offset(read_status(leader)[-1], read_status(follower)[-1])
    assert truth == pytest.approx(-26.42, abs=2.0)  # agents start within 2 s of each other
    assert abs(view["offset"] - truth) < 0.002, (view["offset"], truth)
    assert 0 < view["delay"] < 0.005
    assert view["rejected"] == 0
    # The leader queries the follower too (the paper's two channels), with the opposite sign.
    back = peer_view(leader, FOLLOWER)
    assert back is not None and back["samples"] > 0
    assert abs(back["offset"] + truth) < 0.002
    # The follower tracks the leader's heading on simulation time (Eq. 5).
    line = last_status(follower)
    assert line is not None and line["reference"] == LEADER
    assert line["t_sim"] == pytest.approx(line["t_exec"] + view["offset"], abs=1e-9)
    assert line["counters"]["pose_received"] > 0
    # SIGTERM stops every process cleanly with exit code 0.
    assert fleet.stop(f"rome-{FOLLOWER.split('/')[1]}") == 0
    assert fleet.stop("kiruna-knatte") == 0
    assert fleet.stop("router-rome") == 0
    assert fleet.stop("router-kiruna") == 0


def test_four_agents_in_two_labs_find_each_other_by_name(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna, rome = two_labs(fleet, endpoint)
    names = {
        "kiruna/knatte": kiruna,
        "kiruna/ghost": kiruna,
        "rome/pinocchio": rome,
        "rome/ada": rome,
    }
    files = {}
    for agent, ep in names.items():
        if agent == LEADER:
            files[agent] = start_agent(fleet, tmp_path, "leader", agent, ep)
        else:
            files[agent] = start_agent(fleet, tmp_path, "follower", agent, ep, "--follow", LEADER)

    def everyone_synced() -> bool:
        for agent, path in files.items():
            line = last_status(path)
            if line is None:
                return False
            others = set(names) - {agent}
            if set(line["peers"]) != others:
                return False
            if any(line["peers"][o]["samples"] < 3 for o in others):
                return False
        return True

    assert wait_for(everyone_synced, timeout=20), {a: last_status(p) for a, p in files.items()}
    first = {a: read_status(p)[-1] for a, p in files.items()}
    for line in first.values():
        for other, view in line["peers"].items():
            assert view["alive"]
            assert abs(view["offset"] - true_offset(first[other], line)) < 0.002

    # One agent leaves; the others see its token go within the status period.
    fleet.stop("rome-ada")
    assert wait_for(
        lambda: all(
            not (last_status(p) or {"peers": {}})["peers"].get("rome/ada", {"alive": True})["alive"]
            for a, p in files.items()
            if a != "rome/ada"
        ),
        timeout=10,
    )


def test_agent_waits_for_its_router_and_survives_router_restart(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna, rome = endpoint(), endpoint()
    # The follower starts before any router exists.
    follower = start_agent(
        fleet, tmp_path, "follower", FOLLOWER, rome, "--follow", LEADER, "--clock-offset", "-3.5"
    )
    time.sleep(1.5)
    assert fleet.alive("rome-pinocchio")
    start_router(fleet, "kiruna", kiruna)
    leader = start_agent(fleet, tmp_path, "leader", LEADER, kiruna)
    start_router(fleet, "rome", rome, connect=kiruna)
    assert wait_for(lambda: samples(follower, LEADER) >= 5, timeout=20), "never joined"

    # Kill the dialling router as a crash would, then bring it back on the same port.
    fleet.kill("router-rome")
    before = samples(follower, LEADER)
    time.sleep(1.0)
    assert samples(follower, LEADER) <= before + 1  # nothing crosses without the router
    assert fleet.alive("rome-pinocchio") and fleet.alive("kiruna-knatte")
    restarted = time.monotonic()
    start_router(fleet, "rome", rome, connect=kiruna)
    resumed = samples(follower, LEADER) + 5
    assert wait_for(lambda: samples(follower, LEADER) >= resumed, timeout=15), "sync never resumed"
    took = time.monotonic() - restarted
    assert took < 10, f"sync resumed only after {took:.1f} s"
    view = peer_view(follower, LEADER)
    assert view is not None
    truth = true_offset(read_status(leader)[-1], read_status(follower)[-1])
    assert abs(view["offset"] - truth) < 0.002
    assert fleet.alive("rome-pinocchio") and fleet.alive("kiruna-knatte")


def test_malformed_sync_requests_get_no_reply_and_are_counted(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna = endpoint()
    start_router(fleet, "kiruna", kiruna)
    leader = start_agent(fleet, tmp_path, "leader", LEADER, kiruna)
    assert wait_for(lambda: last_status(leader) is not None, timeout=10)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{kiruna}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    key = "fedlab/default/kiruna/knatte/sync"
    bad = {
        "7 bytes": b"\x00" * 7,
        "9 bytes": b"\x00" * 9,
        "NaN": struct.pack("<d", math.nan),
        "inf": struct.pack("<d", math.inf),
        "empty": b"",
    }
    with zenoh.open(conf) as session:
        for payload in bad.values():
            replies = list(session.get(key, payload=payload, timeout=1.0))
            assert [r for r in replies if r.ok is not None] == []
        good = list(session.get(key, payload=struct.pack("<d", 1.5), timeout=1.0))
        oks = [r.ok for r in good if r.ok is not None]
        assert len(oks) == 1
        reply = oks[0].payload.to_bytes()
        assert len(reply) == 64
        t1, t2 = struct.unpack_from("<2d", reply)
        assert t1 == 1.5 and t2 > 0

    def counted() -> bool:
        line = last_status(leader)
        return line is not None and line["counters"].get("sync_requests_malformed", 0) == len(bad)

    assert wait_for(counted, timeout=5), last_status(leader)
    log = fleet.log_path("kiruna-knatte").read_text()
    assert "rejected sync request" in log and "expected 8 bytes, got 7" in log
    assert fleet.alive("kiruna-knatte")

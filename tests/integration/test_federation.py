"""Integration: real routers and agents as separate processes on loopback.

Every wait is bounded; every process is stopped by pid (the ``labs`` fixture);
every Zenoh session opened here is closed.
"""

from __future__ import annotations

import math
import struct
import time

import pytest
import zenoh
from loopback import FOLLOWER, LEADER, Labs, client_config, offset_error

from federation.fleet.launch import wait_for
from federation.report.status import true_offset

pytestmark = pytest.mark.integration


def test_follower_estimates_leader_clock_across_two_labs(labs: Labs) -> None:
    pair = labs.pair()
    leader = labs.leader(pair.kiruna)
    follower = labs.follower(pair.rome, "--clock-offset", "26.42")
    follower.wait_samples(LEADER, 20, timeout=15)

    view = follower.peer(LEADER)
    assert view is not None
    truth = true_offset(leader.latest(), follower.latest())
    assert truth == pytest.approx(-26.42, abs=2.0)  # agents start within 2 s of each other
    offset_error(view, truth)
    assert 0 < view["delay"] < 0.005
    assert view["rejected"] == 0
    # The leader queries the follower too (the paper's two channels), with the opposite
    # sign: once a second, so its estimate comes with the third exchange, 2 to 3 s in.
    line = leader.until(
        lambda line: (line["peers"].get(FOLLOWER) or {}).get("offset") is not None,
        timeout=10,
        what=f"the leader's estimate of {FOLLOWER}'s clock",
    )
    back = line["peers"][FOLLOWER]
    assert back["samples"] >= 3
    offset_error(back, -truth)
    # The follower tracks the leader's heading on simulation time (Eq. 5).
    line = follower.last()  # its offset then, of that line: each sample moves the estimate
    assert line is not None and line["reference"] == LEADER
    offset = line["peers"][LEADER]["offset"]
    assert line["t_sim"] == pytest.approx(line["t_exec"] + offset, abs=1e-9)
    assert line["counters"]["pose_received"] > 0
    # SIGTERM stops every process cleanly with exit code 0.
    assert follower.stop() == 0
    assert leader.stop() == 0
    assert pair.rome.stop() == 0
    assert pair.kiruna.stop() == 0


def test_four_agents_in_two_labs_find_each_other_by_name(labs: Labs) -> None:
    pair = labs.pair()
    names = {
        "kiruna/knatte": pair.kiruna,
        "kiruna/ghost": pair.kiruna,
        "rome/pinocchio": pair.rome,
        "rome/ada": pair.rome,
    }
    agents = {
        # --sync-all: pairwise sync with everyone (the default syncs with the reference only)
        who: labs.leader(at) if who == LEADER else labs.follower(at, "--sync-all", who=who)
        for who, at in names.items()
    }

    def everyone_synced() -> bool:
        for who, agent in agents.items():
            line = agent.last()
            if line is None:
                return False
            others = set(names) - {who}
            if set(line["peers"]) != others:
                return False
            if any(line["peers"][o]["samples"] < 3 for o in others):
                return False
        return True

    assert wait_for(everyone_synced, timeout=20), {a: p.last() for a, p in agents.items()}
    first = {who: agent.latest() for who, agent in agents.items()}
    for line in first.values():
        for other, view in line["peers"].items():
            assert view["alive"]
            offset_error(view, true_offset(first[other], line))

    # One agent leaves; the others see its token go within the status period.
    agents["rome/ada"].stop()
    assert wait_for(
        lambda: all(
            not (p.last() or {"peers": {}})["peers"].get("rome/ada", {"alive": True})["alive"]
            for a, p in agents.items()
            if a != "rome/ada"
        ),
        timeout=10,
    )


def test_agent_waits_for_its_router_and_survives_router_restart(labs: Labs) -> None:
    kiruna, rome = labs.endpoint(), labs.endpoint()
    # The follower starts before any router exists.
    follower = labs.follower(rome, "--clock-offset", "-3.5")
    # It says so after 2 s of waiting for its router, and waits on.
    waiting = "waiting for the router"
    assert wait_for(lambda: waiting in follower.log(), timeout=30), follower.log()[-2000:]
    assert follower.alive()
    labs.router("kiruna", listen=kiruna)
    leader = labs.leader(kiruna)
    router_rome = labs.router("rome", listen=rome, connect=kiruna)
    follower.wait_samples(LEADER, 5, timeout=20)  # it joins once both routers are up

    # Kill the dialling router as a crash would, then bring it back on the same port.
    router_rome.kill()
    before = follower.samples(LEADER)
    time.sleep(1.0)  # a second without the router
    assert follower.samples(LEADER) <= before + 1  # nothing crosses without the router
    assert follower.alive() and leader.alive()
    restarted = time.monotonic()
    router_rome.start()
    resumed = follower.samples(LEADER) + 5
    follower.wait_samples(LEADER, resumed, timeout=15)
    took = time.monotonic() - restarted
    assert took < 10, f"sync resumed only after {took:.1f} s"
    view = follower.peer(LEADER)
    assert view is not None
    truth = true_offset(leader.latest(), follower.latest())
    offset_error(view, truth)
    assert follower.alive() and leader.alive()


def test_malformed_sync_requests_get_no_reply_and_are_counted(labs: Labs) -> None:
    kiruna = labs.router("kiruna")
    leader = labs.leader(kiruna)
    leader.wait_status(timeout=10)

    key = "fedlab/default/kiruna/knatte/sync"
    bad = {
        "7 bytes": b"\x00" * 7,
        "9 bytes": b"\x00" * 9,
        "NaN": struct.pack("<d", math.nan),
        "inf": struct.pack("<d", math.inf),
        "empty": b"",
    }
    with zenoh.open(client_config(kiruna.endpoint)) as session:
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

    leader.until(
        lambda line: line["counters"].get("sync_requests_malformed", 0) == len(bad),
        timeout=5,
        what="every malformed request counted",
    )
    log = leader.log()
    assert "rejected sync request" in log and "expected 8 bytes, got 7" in log
    assert leader.alive()

"""A lab whose agents run on more than one host (federation/testbed, ``rome_hosts=2``).

Rome's lab network has two hosts behind its masquerading gateway: ``rome``
(192.0.2.10) runs the lab router, ``rome2`` (192.0.2.11) runs a follower whose
session dials that router over the lab network. Kiruna's leader is across the WAN
(20 ms one way through the packet stage). The follower needs only its lab router's
address: it syncs with the leader and follows its pose through the two routers,
while nothing outside the lab can open a connection to its host. With three hosts,
``rome2`` and ``rome3`` each run three followers as one ``fedlab host`` process.
Needs root, nftables and /dev/net/tun; skips saying which is missing.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from federation.fleet.launch import wait_for
from federation.link.packet import PacketOptions
from federation.report.status import last_status
from federation.testbed import ADDR, PREFIX, Testbed, leftover_namespaces, missing

WHY = missing()
pytestmark = [
    pytest.mark.integration,
    pytest.mark.testbed,
    pytest.mark.scenario,
    pytest.mark.skipif(WHY is not None, reason=f"network testbed: {WHY}"),
]

ROUTERS = Path(__file__).resolve().parents[2] / "deploy" / "routers"
PORT = 7447
LEADER = "kiruna/knatte"
ROME_ROUTER = f"tcp/{ADDR.rome}:{PORT}"  # on the lab network, not loopback


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """A test that leaves a namespace of this process behind fails."""
    mine = f"{PREFIX}{os.getpid()}x"
    yield
    assert leftover_namespaces(mine) == []


def _established(bed: Testbed, host: str) -> list[tuple[str, str]]:
    """(local, peer) address:port of every established TCP connection on ``host``."""
    out = bed.run(host, "ss", "-H", "-t", "-n", "state", "established")
    return [(f[2], f[3]) for f in (line.split() for line in out.splitlines()) if len(f) >= 4]


def start_routers_and_leader(bed: Testbed) -> None:
    """Both labs' routers (Rome's on its lab network, dialling Kiruna across the WAN)
    and Kiruna's leader, for 60 s."""
    bed.fedlab(
        "kiruna",
        "router-kiruna",
        ["router", "-c", str(ROUTERS / "kiruna.json5"), "--open", "-l", f"tcp/0.0.0.0:{PORT}"],
    )
    bed.fedlab(
        "rome",
        "router-rome",
        ["router", "-c", str(ROUTERS / "rome.json5"), "--open", "-l", ROME_ROUTER,
         "-e", f"tcp/{ADDR.kiruna}:{PORT}"],
    )  # fmt: skip
    bed.fedlab(
        "kiruna",
        "leader",
        ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte",
         "-e", f"tcp/127.0.0.1:{PORT}", "--status-period", "0.5", "--duration", "60"],
    )  # fmt: skip


def test_an_agent_on_a_second_lab_host_needs_only_its_lab_router(tmp_path: Path) -> None:
    status = tmp_path / "follower.jsonl"
    t0 = time.monotonic()
    with Testbed(tmp_path, PacketOptions(delay=0.02), rome_hosts=2) as bed:
        built = time.monotonic() - t0
        rome2 = ADDR.rome_host("rome2")
        start_routers_and_leader(bed)
        common = ["--status-period", "0.5", "--duration", "60"]
        bed.fedlab(
            "rome2",
            "follower",
            ["agent", "--role", "follower", "--lab", "rome", "--name", "pinocchio",
             "--follow", LEADER, "-e", ROME_ROUTER, "--status-json", str(status),
             "--sync-window", "3", *common],  # locked after 3 s of exchanges, not 10
        )  # fmt: skip
        started = time.monotonic()
        seen: list[dict[str, Any]] = []

        def following() -> bool:
            line = last_status(status)
            if line is None:
                return False
            seen[:] = [line]
            leader = line["peers"].get(LEADER, {})
            return bool(
                leader.get("locked")
                and leader.get("samples", 0) >= 10
                and line["counters"].get("pose_received", 0) >= 20
                and line["hold"] is None
                and line["pose_age"] is not None
                and line["pose_age"] < 0.25
            )

        assert wait_for(following, 30.0, 0.2), (
            f"the follower on rome2 did not sync with and follow {LEADER} within 30 s; "
            f"last status {seen[0] if seen else None}\n{bed.log('follower')[-2000:]}"
        )
        following_after = time.monotonic() - started
        line = seen[0]

        # The follower's host holds one connection: to its lab router, on the lab network.
        conns = _established(bed, "rome2")
        assert [peer for _, peer in conns] == [f"{ADDR.rome}:{PORT}"], conns
        assert conns[0][0].startswith(f"{rome2}:"), conns
        # Rome's router sees it there, and is the one that crosses to Kiruna.
        on_router = _established(bed, "rome")
        assert any(local == f"{ADDR.rome}:{PORT}" and peer.startswith(f"{rome2}:")
                   for local, peer in on_router)  # fmt: skip
        assert any(peer == f"{ADDR.kiruna}:{PORT}" for _, peer in on_router)
        stage = bed.stage_stats()  # ... through the WAN's packet stage, both ways
        assert stage["forward"]["delivered"] > 0 and stage["backward"]["delivered"] > 0
        # Not because the network forbids more: through the NAT rome2 could reach Kiruna.
        assert bed.probe("rome2", ADDR.kiruna, PORT, 2.0) == "connected"
        # Into rome2: reachable on the lab network (nothing listens: refused), but a
        # direct connection from Kiruna meets the gateway's firewall (dropped: timeout).
        assert bed.probe("rome", rome2, PORT, 2.0) == "refused"
        assert bed.probe("kiruna", rome2, PORT, 2.0) == "timeout"
        closing = time.monotonic()
    closed = time.monotonic() - closing
    # Every session closed on SIGTERM (the stage outlives the routers): none killed.
    exits = {name: proc.returncode for name, proc in bed.fleet.procs.items()}
    assert exits == dict.fromkeys(
        ["router-kiruna", "router-rome", "leader", "follower", "stage"], 0
    )
    print(
        f"\ntestbed built in {built:.1f} s; follower on rome2 synced and following after "
        f"{following_after:.1f} s: {line['peers'][LEADER]['samples']} sync samples, "
        f"{line['counters']['pose_received']} poses, pose age {line['pose_age'] * 1e3:.0f} ms; "
        f"everything stopped and removed in {closed:.1f} s"
    )


def test_a_lab_runs_its_agents_as_hosted_processes_on_two_hosts(tmp_path: Path) -> None:
    """Rome's six followers run as two ``fedlab host`` processes of three, on rome2 and
    rome3: each process holds one connection (to the lab router), and its three agents
    share one sync exchange with the leader (one clock per process)."""
    groups = {"rome2": ("a1", "a2", "a3"), "rome3": ("b1", "b2", "b3")}
    files: dict[str, list[str]] = {}
    for host, names in groups.items():
        files[host] = []
        for name in names:
            path = tmp_path / f"{name}.toml"
            path.write_text(
                f'lab = "rome"\nname = "{name}"\nrole = "follower"\nfollow = "{LEADER}"\n'
                f"status_period = 0.5\nsync_window = 3.0\nduration = 60.0\n"
            )
            files[host].append(str(path))
    status = tmp_path / "status"
    with Testbed(tmp_path, PacketOptions(delay=0.02), rome_hosts=3) as bed:
        start_routers_and_leader(bed)
        for host in groups:
            bed.fedlab(
                host, f"host-{host}",
                ["host", *files[host], "-e", ROME_ROUTER, "--status-dir", str(status)],
            )  # fmt: skip
        names = [name for group in groups.values() for name in group]
        seen: dict[str, dict[str, Any]] = {}
        started = time.monotonic()

        def everyone_follows() -> bool:
            for name in names:
                line = last_status(status / f"rome-{name}.jsonl")
                if line is None:
                    return False
                seen[name] = line
                leader = line["peers"].get(LEADER, {})
                if not (
                    leader.get("locked")
                    and line["counters"].get("pose_received", 0) >= 20
                    and line["hold"] is None
                    and line["pose_age"] is not None
                    and line["pose_age"] < 0.25
                ):
                    return False
            return True

        assert wait_for(everyone_follows, 40.0, 0.2), (
            f"not every hosted follower synced with and followed {LEADER} within 40 s; "
            f"last status {seen}\n{bed.log('host-rome2')[-1500:]}\n{bed.log('host-rome3')[-1500:]}"
        )
        following_after = time.monotonic() - started
        for name in names:  # three agents on one exchange, per process
            assert seen[name]["peers"][LEADER]["sharing"] == 3, seen[name]["peers"]
        for host in groups:  # one connection per process, to the lab router
            conns = _established(bed, host)
            assert [peer for _, peer in conns] == [f"{ADDR.rome}:{PORT}"], (host, conns)
    exits = {name: proc.returncode for name, proc in bed.fleet.procs.items()}
    assert exits == dict.fromkeys(
        ["router-kiruna", "router-rome", "leader", "host-rome2", "host-rome3", "stage"], 0
    )
    ages = [seen[name]["pose_age"] * 1e3 for name in names]
    print(
        f"\nsix hosted followers on rome2 and rome3 locked and following after "
        f"{following_after:.1f} s; pose ages {min(ages):.0f} to {max(ages):.0f} ms"
    )


def test_a_failure_removes_the_extra_hosts_and_the_switch_too(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="boom"), Testbed(tmp_path, rome_hosts=3) as bed:
        names = set(bed.ns.values())
        assert {"rome2", "rome3", "rome-lan"} <= set(bed.ns)
        assert names <= set(leftover_namespaces())
        raise RuntimeError("boom")
    assert not names & set(leftover_namespaces())

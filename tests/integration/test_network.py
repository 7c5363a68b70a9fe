"""The federation on real network stacks (federation/testbed): Rome behind a
masquerading gateway with a stateful firewall, Kiruna with its router's ports open,
the paper's path between them (40 ms one way, 3 ms jitter) through the packet stage.

Short versions of the committed ``fedlab bench network`` runs
(benchmarks/network-*.json): the same code, with a 5 s sync phase instead of 10
(the offset estimate is within 0.5 ms after 4 s on this path; the MTU black
hole's test keeps 10, see there) and about 13 s
scored instead of 65 (``SECONDS`` plus the agents' 5 s start-up margin, see
``network.run_one``), on the default router configs with the shipped host TCP
settings (``tcp-tuned``). Needs root, nftables and /dev/net/tun; skips saying which
is missing. Every test checks that its namespaces are gone afterwards; each
testbed's names carry the pid, and one testbed runs on the host at a time
(``HOST_LOCK``), so these run beside other tests on parallel workers.

A hold on a clean path is a failure: the testbed runs its packet stage at
real-time priority with its counters in memory, and the labs' processes ahead of
the other tests' (federation/testbed/bed.py), so a busy host does not stretch the
path. A hold can still come from the federation's own processes starved on a
heavily loaded host (the leader sending a pose late), as it would on a lab host
that busy: the message says the leader's longest pause.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from federation.bench import network
from federation.bench.network import FOLLOWER, LEADER
from federation.core.linkwatch import MAX_STALE
from federation.core.preflight import preflight
from federation.fleet.launch import wait_for
from federation.link.packet import PacketOptions
from federation.report.status import read_status
from federation.runtime.monitor import MonitorModel
from federation.testbed import ADDR, PREFIX, Testbed, leftover_namespaces, missing

WHY = missing()
pytestmark = [
    pytest.mark.integration,
    pytest.mark.testbed,
    pytest.mark.skipif(WHY is not None, reason=f"network testbed: {WHY}"),
]

ONE_WAY = 0.040  # s, the paper's path
POSE_PERIOD = 0.05  # s, 20 Hz
SECONDS = 8.0  # run beyond the sync phase (the benchmark: 60); about 13 s are scored
SYNC_PHASE = 5.0  # s (the benchmark: 10)


def _why_held(result: dict[str, Any]) -> str:
    """What a failed ``holds == 0`` says: the leader's longest pause between poses
    (a late pose from the leader's own host, not the path), the latency and the stage."""
    return (
        f"{result['holds']} holds; leader's longest pause {result['sender_gap_max_ms']} ms, "
        f"pose latency {result['pose_latency_ms']}, stage {result['stage']}"
    )


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """A test that leaves a namespace of this process behind fails."""
    mine = f"{PREFIX}{os.getpid()}x"
    yield
    assert leftover_namespaces(mine) == []


def test_nat_lets_the_federation_through_and_nothing_in(tmp_path: Path) -> None:
    result = network.run_one(
        network.SCENARIOS["clean"], "tcp-tuned", 4.0, tmp_path, sync_phase=SYNC_PHASE
    )
    assert result["poses_received"] > 100
    assert result["sync_error_ms"]["n"] > 50
    assert result["holds"] == 0, _why_held(result)
    # Direct connections from Kiruna into Rome's lab, and to its public address, fail.
    assert result["nat_probe"] == {"rome_host": "timeout", "rome_gateway": "timeout"}
    # A raw Zenoh client on Rome's router gets Kiruna's poses through the same NAT.
    assert result["outside_subscriber"]["leader_poses"] > 100


def test_a_failure_inside_the_testbed_still_removes_everything(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="boom"), Testbed(tmp_path, PacketOptions()) as bed:
        stage = bed.fleet.procs["stage"]
        names = list(bed.ns.values())
        raise RuntimeError("boom")
    assert stage.poll() is not None  # stopped by pid
    assert not set(names) & set(leftover_namespaces())


def test_the_stage_carries_tcp_with_the_path_delay(tmp_path: Path) -> None:
    with Testbed(tmp_path, PacketOptions(delay=ONE_WAY)) as bed:
        # A closed port answers with a reset: one round trip through the stage.
        assert bed.probe("rome", ADDR.kiruna, 7447, 2.0) == "refused"

        def both_ways() -> bool:  # the stage writes its counters every second
            stats = bed.stage_stats()
            return stats["forward"]["delivered"] >= 1 and stats["backward"]["delivered"] >= 1

        assert wait_for(both_ways, 3.0)
        # The stage runs before every ordinary process: a busy host does not stretch the path.
        assert bed.stage_scheduling in ("fifo", "nice")
    assert (tmp_path / "stage.json").exists()  # its last counters, kept with the run


@pytest.mark.scenario
def test_five_percent_loss_on_tcp_no_stale_pose_and_sync_accurate(tmp_path: Path) -> None:
    result = network.run_one(
        network.SCENARIOS["loss5"], "tcp-tuned", SECONDS, tmp_path, sync_phase=SYNC_PHASE
    )
    # A pose held behind a lost segment is dropped on arrival once older than the
    # link's delay plus the stale threshold (at most 0.25 s): the controller never
    # steers by an older one. The delay is the follower's estimate (its exchanges'
    # median), which a loaded host's queueing raises above the path's 40 ms; judged
    # against the path's, one pose taken 300.4 ms old beside the parallel workers
    # failed a bound of 300. 10 ms for the offset estimate's error and the recording's
    # stamp.
    latency, beyond = result["pose_latency_ms"], result["pose_age_beyond_delay_ms"]
    print(f"pose latency {latency}; beyond the follower's delay estimate {beyond}")
    assert beyond["max"] <= (0.01 + MAX_STALE) * 1e3
    # The 0.3 ms is the benchmark's (60 s scored: 0.09 and 0.11 ms, docs/deploy.md).
    # A short score on the path's 3 ms jitter has less to average: with about 25 s
    # scored, five runs gave p95 0.04, 0.22, 0.29, 0.43 and (in CI) 0.517 ms, the last
    # the path's own asymmetry on a loaded host, unseen by any timestamp method. After
    # 4 s of exchanges the error is no larger than later in a run (p95 0.1 to 0.4 ms,
    # five clean runs), so the ~13 s scored here keep the bound of 0.75 ms.
    assert result["sync_error_ms"]["p95"] < 0.75
    # An outside raw Zenoh subscriber on Rome's router keeps receiving, as the agent does.
    sub = result["outside_subscriber"]
    assert sub["leader_poses"] >= 0.9 * sub["follower_poses_all_run"]
    assert sub["last_pose_before_end_s"] < 2.0


@pytest.mark.scenario
def test_a_ten_second_cut_holds_fast_and_recovers_without_a_stale_burst(tmp_path: Path) -> None:
    # Cut 1 s after the sync phase, for 10 s; the agents run at least 6 s after the return.
    scenario = network.Scenario("cut10", cut=(1.0, 10.0))
    result = network.run_one(scenario, "tcp-tuned", 12.0, tmp_path, sync_phase=SYNC_PHASE)
    cut = result["cut"]
    lines = read_status(tmp_path / "follower.jsonl")
    # Held within 300 ms of the cut (the stale ceiling, 250 ms, and a 20 Hz control
    # step), plus however late the follower's own control loop ran in this run: on a
    # host shared with parallel workers a step comes late (309 ms was seen), on an idle
    # one the loop's lateness is a few ms.
    late = max((line.get("loop") or {}).get("late_max_ms", 0.0) for line in lines)
    assert cut["hold_after_cut_ms"] is not None, cut
    assert cut["hold_after_cut_ms"] <= 300 + late, (cut, f"loop late at most {late:.1f} ms")
    # How fast pose and sync come back is a speed figure, measured and committed by
    # `fedlab bench network` (benchmarks/network-tcp-tuned-60s.json): here only that
    # they do come back, within a bound a loaded CI host keeps.
    # After a cut past the lease, Rome's router redials at most every 4 s (1 s growing
    # to 4 s): back within that and a fresh session's set-up (5.08 s seen beside
    # parallel tests, 0.5 to 1.6 s on an idle host, docs/deploy.md).
    assert cut["pose_back_after_s"] <= 6.0, cut
    assert cut["sync_back_after_s"] <= 6.0, cut
    assert cut["released_after_s"] is not None
    # No pose queued through the cut reaches the controller.
    assert cut["oldest_pose_after_return_ms"] <= (ONE_WAY + 0.01 + MAX_STALE) * 1e3
    # One hold, the cut's: none flapping after the return. (Counted from the cut, not
    # from the scored start: on a loaded host the agents may start so late that the
    # cut falls in their sync phase.)
    assert cut["holds_from_cut"] == 1
    # Through the cut the leader stays alive (its token outlives the cut) but answers
    # nothing: the follower's status raises the alarm, preflight fails naming the
    # leader, the monitor shows it; after the return the alarm clears.
    silent = [s for s in lines if (s.get("peers") or {}).get(LEADER, {}).get("silent")]
    assert silent, "the follower never reported the leader alive but silent during the cut"
    (row,) = preflight([FOLLOWER], {FOLLOWER: silent[-1]}, {FOLLOWER: 0.0})
    assert not row.checks["peers"].ok and LEADER in row.checks["peers"].detail
    model = MonitorModel()
    model.on_status(f"fedlab/default/{FOLLOWER}/status", json.dumps(silent[-1]).encode(), 0.0)
    assert LEADER in (model.rows(0.0)[0].silent or {})
    assert lines[-1]["peers"][LEADER].get("silent") is None


@pytest.mark.scenario
def test_an_mtu_black_hole_does_not_stop_the_link(tmp_path: Path) -> None:
    # The black hole stops the link for about 4 s after the first exchange, until TCP
    # takes a smaller segment size (tcp_mtu_probing): one hold, then the link runs. The
    # paper's 10 s sync phase leaves that start-up out of the score; a 5 s one does not.
    result = network.run_one(network.SCENARIOS["mtu576"], "tcp-tuned", SECONDS, tmp_path)
    assert (
        result["stage"]["backward"]["dropped"].get("mtu", 0)
        + result["stage"]["forward"]["dropped"].get("mtu", 0)
        > 0
    ), "nothing was too big: the test tested nothing"
    assert result["holds"] == 0, _why_held(result)
    assert result["sync_error_ms"]["n"] >= 0.8 * SECONDS * 10  # exchanges kept completing
    assert result["outside_subscriber"]["status_samples"] > 0

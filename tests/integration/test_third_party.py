"""A third-party agent built from docs/protocol.md alone joins a federation and gets synced.

tests/integration/third_party_agent.py uses raw zenoh calls and no fedlab code; a router and a
fedlab leader run as processes on loopback (bounded waits, stopped by pid).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
from loopback import Labs, offset_error

from federation.fleet.launch import Fleet, wait_for
from federation.report.status import read_status

pytestmark = pytest.mark.integration

RAW = "lab3/raw"
RAW_OFFSET = -7.318  # the raw agent's clock minus the host's monotonic clock
RAW_AGENT = Path(__file__).with_name("third_party_agent.py")


def raw_lines(fleet: Fleet) -> list[dict[str, Any]]:
    """The raw agent's JSON lines from its log (other lines skipped)."""
    return read_status(fleet.log_path("raw"))


def test_raw_zenoh_agent_joins_answers_sync_and_gets_synced(labs: Labs, fleet: Fleet) -> None:
    kiruna = labs.router("kiruna")
    leader = labs.leader(kiruna)
    # The raw agent dials the router; started once the router is up (zenoh.open needs it).
    leader.wait_status(timeout=10)
    fleet.spawn(
        "raw", [sys.executable, str(RAW_AGENT), kiruna.endpoint, RAW, str(RAW_OFFSET), "60"]
    )

    # The leader queries an agent it does not follow once a second.
    assert wait_for(lambda: leader.samples(RAW) >= 8, timeout=15), (
        leader.last(),
        fleet.log_path("raw").read_text()[-2000:],
    )
    line = leader.latest()
    peer = line["peers"][RAW]
    truth = RAW_OFFSET - (line["t_exec"] - line["host_monotonic"])  # raw minus leader
    assert peer["alive"] and peer["samples"] > 0
    error = offset_error(peer, truth)
    assert peer["rejected"] == 0 and peer["timeouts"] == 0
    served = raw_lines(fleet)[-1]["served"]
    assert served > 0
    print(
        f"leader's offset estimate of lab3/raw: error {error * 1e3:+.3f} ms, "
        f"delay {peer['delay'] * 1e3:.3f} ms, samples {peer['samples']}, served {served}"
    )

    # SIGTERM: the raw agent undeclares and closes its session; the leader sees it leave.
    assert fleet.stop("raw") == 0
    assert wait_for(lambda: not (leader.peer(RAW) or {"alive": True})["alive"], timeout=5)

"""fedlab monitor against a real router and two agents: the live view and ``--once --json``.

The table itself (model, renderer, command line) is tested without processes in
tests/unit/runtime/test_monitor_table.py.
"""

from __future__ import annotations

import json
import sys
import threading
import time

import pytest
from loopback import FOLLOWER, LEADER, Labs

from federation import cli
from federation.fleet.launch import Fleet

pytestmark = pytest.mark.integration


def main(args: list[str]) -> int:
    """``fedlab monitor ARGS`` in this process."""
    return cli.main(["monitor", *args])


def test_monitor_shows_a_leader_and_a_follower(
    labs: Labs, fleet: Fleet, capsys: pytest.CaptureFixture[str]
) -> None:
    router = labs.router("kiruna")
    leader = labs.leader(router)
    follower = labs.follower(router)
    # The live view, as a user runs it: stopped by SIGTERM with exit code 0.
    live = [sys.executable, "-m", "federation", "monitor", "-e", router.endpoint]
    fleet.spawn("monitor-live", live)
    follower.wait_samples(LEADER, 3, timeout=15)
    leader.wait_samples(FOLLOWER, 3, timeout=5)

    started = time.monotonic()
    assert main(["--once", "--wait", "4", "--json", "-e", router.endpoint]) == 0
    assert time.monotonic() - started < 10
    snapshot = json.loads(capsys.readouterr().out)
    assert snapshot["federation"] == "default" and snapshot["malformed"] == 0
    rows = {row["agent"]: row for row in snapshot["rows"]}
    assert set(rows) == {LEADER, FOLLOWER}, rows
    leader_row, follower_row = rows[LEADER], rows[FOLLOWER]
    assert (leader_row["role"], follower_row["role"]) == ("leader", "follower")
    assert leader_row["mode"] and follower_row["mode"]
    assert leader_row["offset_s"] == "ref"
    assert isinstance(follower_row["offset_s"], float)
    for row in (leader_row, follower_row):
        assert row["state"] == "ok" and row["alive"], row
        assert 0 < row["delay_s"] < 0.05, row
        assert row["samples"] > 0 and row["rejected"] == 0, row
        assert row["since_status_s"] < 2.0, row

    assert fleet.alive("monitor-live")
    assert fleet.stop("monitor-live") == 0
    shown = fleet.log_path("monitor-live").read_text()
    assert "knatte" in shown and "pinocchio" in shown, shown[-2000:]

    # An agent that stops while the monitor watches is shown as "left".
    leave = threading.Timer(1.0, follower.stop)
    leave.start()
    try:
        assert main(["--once", "--wait", "3", "--json", "-e", router.endpoint]) == 0
    finally:
        leave.join(10)
    rows = {row["agent"]: row for row in json.loads(capsys.readouterr().out)["rows"]}
    assert rows[FOLLOWER]["state"] == "left" and not rows[FOLLOWER]["alive"]
    assert rows[FOLLOWER]["role"] == "follower"  # its last status is kept
    assert rows[LEADER]["state"] == "ok"

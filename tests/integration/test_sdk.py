"""The SDK example against real routers, and refusing a name already taken."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from loopback import LEADER, Labs

from federation.fleet.launch import wait_for

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


def test_sdk_example_joins_and_sees_the_leader(labs: Labs) -> None:
    router = labs.router("kiruna")
    leader = labs.leader(router)
    leader.wait_status(timeout=15)
    ghost = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "ghost_agent.py"),
         str(ROOT / "examples" / "ghost.csv"), router.endpoint, "6"],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert ghost.returncode == 0, ghost.stderr[-2000:]
    lines = [ast.literal_eval(line) for line in ghost.stdout.splitlines() if line.startswith("{")]
    assert len(lines) == 6
    last = lines[-1]
    assert last["time"] is not None  # its own clock: simulation time from the start
    assert LEADER in last["others"]  # the leader's pose, on simulation time
    # The leader synced with the ghost and saw it leave when the example ended.
    view = leader.latest()["peers"]["lab3/ghost"]
    assert view["samples"] >= 3 and view["offset"] is not None  # 1 Hz: not its reference
    assert wait_for(lambda: not leader.latest()["peers"]["lab3/ghost"]["alive"], timeout=5)
    # Its code is about 20 lines: the SDK does the rest.
    code = [
        line for line in (ROOT / "examples" / "ghost_agent.py").read_text().splitlines()
        if line.strip() and not line.strip().startswith(("#", '"""'))
    ]  # fmt: skip
    assert len(code) <= 30, len(code)


def test_a_taken_name_is_refused_clearly(labs: Labs) -> None:
    router = labs.router("kiruna")
    first = labs.leader(router, status_period=None)
    first.wait_status(timeout=15)
    second = subprocess.run(
        [sys.executable, "-m", "federation", *labs.agent_args(LEADER, router, role="leader")],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert second.returncode == 2
    assert "kiruna/knatte is already in federation default" in second.stderr
    assert first.alive()

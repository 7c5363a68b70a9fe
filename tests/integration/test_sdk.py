"""The SDK example against real routers, and refusing a name already taken."""

from __future__ import annotations

import ast
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from loopback import LEADER, Labs, answer_sync, client_config

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


def test_a_second_process_under_its_name_at_start_holds_the_agent_for_good(
    labs: Labs,
) -> None:
    """The race the start-up check cannot see: a second holder of the name that declares
    it right after the agent has (both passed the check before either declared). The
    agent's look 2 s after start hears two sessions answer its sync key: it holds, says
    why, is not ready, and stays held once the other has gone. (A second fedlab agent
    would do the same on its side.)"""
    router = labs.router("kiruna")
    key = f"fedlab/default/{LEADER}"
    conf = client_config(router.endpoint)
    conf.insert_json5("connect/timeout_ms", "10000")  # the router may still be starting
    racer = zenoh.open(conf)
    tokens: list[Any] = []
    up = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            up.set()

    watch = racer.liveliness().declare_subscriber(key, on_token)
    try:
        leader = labs.leader(router)
        assert up.wait(30), "the agent never declared its name"
        # Within ms of the agent's declarations, as a second `fedlab agent` makes them.
        tokens.append(racer.liveliness().declare_token(key))
        tokens.append(racer.declare_queryable(f"{key}/sync", answer_sync))
        held = leader.until(lambda line: line.get("hold") == "name_taken", 10, "name hold")
        assert held["counters"].get("name_taken_holds") == 1, held["counters"]
        assert held["ready"]["platform"] is False
        assert "name_taken" in held["ready"]["platform_detail"]
        assert "2 processes answer for kiruna/knatte in federation default" in leader.log()
        while tokens:  # the other one stops: this one stays held
            tokens.pop().undeclare()
        left = time.monotonic()
        # Its status 3 s after the other left: still held.
        line = leader.until(lambda line: line["host_monotonic"] >= left + 3.0, 10, "3 s on")
        assert line["hold"] == "name_taken" and line["counters"]["name_taken_holds"] == 1, line
        assert leader.alive()
    finally:
        for token in tokens:
            token.undeclare()
        watch.undeclare()  # type: ignore[no-untyped-call]
        racer.close()  # type: ignore[no-untyped-call]

"""Execution control with real processes: a synchronized start and an abort into safe hold."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from federation.fleet.launch import Fleet, wait_for
from federation.report.status import clock_line, last_status
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENT = ROOT / "deploy" / "experiments" / "attitude-tracking.toml"


def ctl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "federation", "ctl", *args],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip


def test_start_is_simultaneous_and_abort_holds_within_200_ms(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    kiruna, rome = endpoint(), endpoint()
    fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
    fleet.start("router-rome", ["router", "--lab", "rome", "-l", rome, "-e", kiruna])
    agents = {"kiruna/knatte": kiruna, "rome/pinocchio": rome}
    for agent, ep in agents.items():
        lab, name = agent.split("/")
        fleet.start(
            f"{lab}-{name}",
            ["agent", "--experiment", str(EXPERIMENT), "--lab", lab, "--name", name, "-e", ep,
             "--clock-offset", "26.42" if lab == "rome" else "0", "--status-period", "0.5",
             "--status-json", str(tmp_path / f"{lab}-{name}.jsonl"),
             "--record", str(tmp_path / f"{lab}-{name}.mcap")],
        )  # fmt: skip

    def synced() -> bool:
        line = last_status(tmp_path / "rome-pinocchio.jsonl")
        return line is not None and line["t_sim"] is not None and line["mode"] == "waiting"

    assert wait_for(synced, timeout=20)
    started = ctl("start", "--experiment", str(EXPERIMENT), "--in", "2", "-e", rome)
    assert started.returncode == 0, started.stdout + started.stderr
    assert wait_for(
        lambda: all(
            (last_status(tmp_path / f"{a.replace('/', '-')}.jsonl") or {}).get("mode") == "running"
            for a in agents
        ),
        timeout=10,
    )
    aborted = ctl("abort", "--experiment", str(EXPERIMENT), "-e", kiruna)
    assert aborted.returncode == 0, aborted.stdout + aborted.stderr
    for agent in agents:
        fleet.stop(agent.replace("/", "-"))

    # Truth: every clock as a linear function of the host's monotonic clock.
    rec = {a: read_messages(tmp_path / f"{a.replace('/', '-')}.mcap") for a in agents}
    a_ref, b_ref = clock_line(rec["kiruna/knatte"]["/status"])

    def reference_time(host: float) -> float:
        return a_ref + b_ref * host

    for agent in agents:
        control = rec[agent]["/control"]
        start = next(e for e in control if e["event"] == "started")
        command = next(
            e for e in control if e["event"] == "command" and e["command"]["command"] == "start"
        )
        at = command["at"]
        error = reference_time(start["host_monotonic"]) - at
        print(f"{agent}: started {error * 1e3:+.2f} ms from the common instant")
        assert abs(error) < 0.010, agent

        abort_cmd = next(
            e for e in control if e["event"] == "command" and e["command"]["command"] == "abort"
        )
        held = next(e for e in control if e["event"] == "aborted")
        hold_latency = reference_time(held["host_monotonic"]) - abort_cmd["command"]["issued_at"]
        print(f"{agent}: safe hold {hold_latency * 1e3:.1f} ms after ctl sent abort")
        assert 0 <= hold_latency < 0.200, agent
        after = [
            r for r in rec[agent]["/reference"] if r["host_monotonic"] > held["host_monotonic"]
        ]
        assert after and all(r["valves_open"] == 0 for r in after)
        assert all(r["mode"] == "aborted" for r in after)
        # The leader flew its maneuver between start and abort; the follower tracked it.
        running = [r for r in rec[agent]["/reference"] if r["mode"] == "running"]
        assert running

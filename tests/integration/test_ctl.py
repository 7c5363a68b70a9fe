"""Execution control with real processes: a synchronized start and an abort into safe hold."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from inprocess import fedlab_here
from lifecycle import QUICK_LOCK
from loopback import Labs

from federation.fleet.launch import wait_for
from federation.report.status import clock_line
from federation.runtime.control import START_IN_MIN
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENT = ROOT / "deploy" / "experiments" / "attitude-tracking.toml"


def ctl(*args: str) -> subprocess.CompletedProcess[str]:
    """``fedlab ctl ARGS`` in the test's process: what is timed here is the agents'
    start and hold, from the instants ctl stamps, not ctl's own process."""
    return fedlab_here("ctl", *args)


@pytest.mark.timing
def test_start_is_simultaneous_and_abort_holds_within_200_ms(labs: Labs) -> None:
    """The paper's experiment file, each agent locking its estimate 2 s after its first
    exchange (QUICK_LOCK), not after the paper's 10 s sync phase: on loopback the
    follower started 0.04 ms from the common instant after 10 s, 0.05 to 0.53 ms after
    2 s (three runs), the bound asserted 10 ms. The start is announced the least ctl
    allows ahead (START_IN_MIN, 1 s)."""
    pair = labs.pair()
    agents = {
        who: labs.agent(
            who, at, "--experiment", str(EXPERIMENT), *QUICK_LOCK,
            "--clock-offset", "26.42" if at is pair.rome else "0", record=True,
        )
        for who, at in {"kiruna/knatte": pair.kiruna, "rome/pinocchio": pair.rome}.items()
    }  # fmt: skip

    agents["rome/pinocchio"].until(
        lambda line: (
            (line.get("ready") or {}).get("reference_locked") and line["mode"] == "waiting"
        ),
        timeout=30,
        what="locked on the reference clock (preflight), waiting for the start",
    )
    started = ctl(
        "start", "--experiment", str(EXPERIMENT), "--in", f"{START_IN_MIN:g}",
        "-e", pair.rome.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    assert wait_for(
        lambda: all((a.last() or {}).get("mode") == "running" for a in agents.values()),
        timeout=10,
    )
    # Freeze and resume at reference instants ctl announced ahead, the same for both labs.
    for action, mode in (("freeze", "frozen"), ("resume", "running")):
        done = ctl(action, "--experiment", str(EXPERIMENT), "-e", pair.rome.endpoint)
        assert done.returncode == 0, done.stdout + done.stderr
        assert all((a.last() or {}).get("mode") == mode for a in agents.values())
    assert "resume at reference time" in done.stdout + done.stderr
    aborted = ctl("abort", "--experiment", str(EXPERIMENT), "--json", "-e", pair.kiruna.endpoint)
    assert aborted.returncode == 0, aborted.stdout + aborted.stderr
    sent = json.loads(aborted.stdout)["sent_monotonic"]  # this host's clock, as the agents'
    for process in agents.values():
        process.stop()

    # Truth: every clock as a linear function of the host's monotonic clock.
    rec = {who: read_messages(agent.record) for who, agent in agents.items()}
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

        # Resumed at the instant the command carries (on the reference clock).
        (resume,) = [
            e["command"] for e in control
            if e["event"] == "command" and e["command"]["command"] == "resume"
        ]  # fmt: skip
        (resumed,) = [e for e in control if e["event"] == "resumed"]
        assert resume["at"] is not None and resume["at"] > resume["issued_at"]
        assert resumed["t_sim"] == pytest.approx(resume["at"], abs=1e-9), agent

        held = next(e for e in control if e["event"] == "aborted")
        hold_latency = held["host_monotonic"] - sent
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

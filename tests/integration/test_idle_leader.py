"""Issue 40's idle leader, the processes' part: a simulated leader on loopback flies a
short run, then a confirmed ``fedlab ctl reset``, from done and from aborted, leaves
none of the holds a reset lifts; its status never shows a hold that is not the run's
own (nor an abort's, once aborted).

The 3 minutes idle on a steep table, out of the camera's view and back without holding
for a fault it does not have, is tests/unit/runtime/test_idle_leader_drift.py's: the same
agent, built from the same experiment, on simulated time. A reset lifting a restarted
estimate in every mode is tests/unit/runtime/test_run_holds.py's.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from lifecycle import as_json, fedlab
from loopback import LEADER, Agent, Labs

from federation.core.holds import RULES, Trigger

pytestmark = [pytest.mark.integration, pytest.mark.scenario]

RUN = 1.0  # s: the run
RUNS_OWN = {None, "waiting", "done", "reset"}  # None: the valves may open (running)
RESET_LIFTS = {rule.hold.value for rule in RULES if Trigger.OPERATOR_RESET in rule.lifted_by}


def write_experiment(path: Path) -> Path:
    """KNATTE alone on the preset's table, leading a run of :data:`RUN` s (held still)."""
    path.write_text(
        f'name = "idle"\nduration = {RUN}\nstart_delay = 1.5\n'
        "[maneuver]\nstill = 10.0\nduration = 10.0\namplitude_deg = 20.0\n"
        f'[[participants]]\nagent = "{LEADER}"\nrole = "leader"\nplatform = "knatte"\nseed = 0\n',
        encoding="utf-8",
    )
    return path


def ctl(action: str, experiment: Path, endpoint: str, *extra: str) -> dict[str, Any]:
    """``fedlab ctl ACTION --json``, confirmed by every participant; its result."""
    args = ("ctl", action, "--json", "--experiment", str(experiment), "-e", endpoint, *extra)
    done, _ = fedlab(*args)
    assert done.returncode == 0, done.stdout + done.stderr
    result: dict[str, Any] = as_json(done)
    assert result["ok"] and not result["pending"], result
    return result


def reset_lifts(leader: Agent, experiment: Path, endpoint: str, held: str) -> None:
    """``leader`` held for ``held``, a hold a reset lifts: ``fedlab ctl reset`` is
    confirmed, the leader applied it, and no line since has a hold a reset lifts."""
    assert held in RESET_LIFTS and leader.latest()["hold"] == held
    sent = ctl("reset", experiment, endpoint)["command"]
    returned = time.monotonic()
    mine = {"command": "reset", "issuer": sent["issuer"], "seq": sent["seq"], "outcome": "applied"}
    leader.until(lambda line: line["host_monotonic"] > returned, 5, "a line after the reset")
    since = [
        line for line in leader.lines()
        if any(mine.items() <= outcome.items() for outcome in line["commands"])
    ]  # fmt: skip
    assert since, f"reset not applied: {leader.latest()['commands']}"
    holds = {line["hold"] for line in since}
    print(f"reset from {held}: {len(since)} lines since, holds {holds}")
    assert not holds & RESET_LIFTS and since[-1]["mode"] == "waiting", holds


def own_holds_only(lines: list[dict[str, Any]], own: set[str | None]) -> None:
    """No line of ``lines`` holds for anything but ``own``, nor counts a restarted
    estimate (a fault the leader does not have)."""
    faults = [(line["t_exec"], line["hold"]) for line in lines if line["hold"] not in own]
    assert not faults, f"held for a fault it does not have (t_exec, hold): {faults[:3]}"
    for name in ("fix_restarts", "fix_restart_holds"):
        assert all(line["counters"].get(name, 0) == 0 for line in lines), name


def test_a_leader_after_a_run_holds_for_no_fault_and_a_reset_lifts_its_holds(
    labs: Labs, tmp_path: Path
) -> None:
    router = labs.router("kiruna")
    experiment = write_experiment(tmp_path / "idle.toml")
    leader = labs.agent(
        LEADER, router, "--experiment", str(experiment), "--runs-dir", str(tmp_path / "runs")
    )
    leader.until(lambda line: line["mode"] == "waiting" and line["ready"]["platform"], 30, "ready")
    ctl("start", experiment, router.endpoint, "--run-id", "short")
    done = leader.until(lambda line: line["mode"] == "done", RUN + 15, "the run done")
    lines = leader.lines()
    assert any(line["mode"] == "running" for line in lines)
    after = [line for line in lines if line["host_monotonic"] >= done["host_monotonic"]]
    assert all(line["mode"] == "done" and line["hold"] == "done" for line in after)

    # A confirmed reset lifts the holds a reset lifts: done after the run, then aborted.
    reset_lifts(leader, experiment, router.endpoint, "done")
    own_holds_only(leader.lines(), RUNS_OWN)
    ctl("abort", experiment, router.endpoint)
    leader.until(lambda line: line["hold"] == "aborted", 5, "held aborted")
    reset_lifts(leader, experiment, router.endpoint, "aborted")
    own_holds_only(leader.lines(), RUNS_OWN | {"aborted"})

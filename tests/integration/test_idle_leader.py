"""Issue 40's idle leader, with real processes on loopback: a simulated leader left idle
for 3 minutes after a run never holds for a fault it does not have, and a confirmed
``fedlab ctl reset`` leaves none of the holds a reset lifts.

The episode: held and idle after a run, KNATTE drifted on the table's slope out of the
camera's view; its estimate dead reckoned for tens of seconds, and when the platform
drifted back the first fixes were gated as outliers of an estimate metres off, five
agreed, the estimate restarted and the leader held (``fix_restart``) until an
operator's reset, for a fault it did not have (fixed in 956aece: fixes after a gap in
the metrology are acquired). On the preset's table that takes about three minutes; this
leader flies a steeper one (tests/integration/data/knatte-steep.toml) that carries it
out of view and back within the idle period. In process, with the GNC of the code
before that fix, this leader, held 4 to 8 s before a 3 s run as here, restarted its
estimate 70 to 87 s into the idle (24 of 24: 8 noise seeds; held 3 to 23 s, 51 to 91 s);
with the fix, never. A reset lifting a restarted estimate in every mode is
tests/unit/runtime/test_run_holds.py's.
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

PLATFORM = Path(__file__).parent / "data" / "knatte-steep.toml"
IDLE = 180.0  # s left idle after the run (issue 40)
RUN = 3.0  # s: the run before it
RUNS_OWN = {None, "waiting", "done", "reset"}  # None: the valves may open (running)
RESET_LIFTS = {rule.hold.value for rule in RULES if Trigger.OPERATOR_RESET in rule.lifted_by}
OUT_OF_VIEW = 10.0  # s without a fix: the estimate dead reckoned, far from the platform


def write_experiment(path: Path) -> Path:
    """KNATTE alone on the steeper table, leading a run of :data:`RUN` s (held still)."""
    path.write_text(
        f'name = "idle"\nduration = {RUN}\nstart_delay = 1.5\n'
        "[maneuver]\nstill = 10.0\nduration = 10.0\namplitude_deg = 20.0\n"
        f'[[participants]]\nagent = "{LEADER}"\nrole = "leader"\n'
        f'platform = "{PLATFORM}"\nseed = 0\n',
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


def out_of_view(lines: list[dict[str, Any]]) -> list[float]:
    """How long (s) each stretch of lines saying the metrology's fix was stale (no fix:
    out of the camera's view) lasted, for those the platform was seen again after."""
    stretches, since = [], None
    for line in lines:
        stale = line["ready"]["platform_detail"] == "metrology fix stale"
        if stale and since is None:
            since = line["host_monotonic"]
        elif not stale and since is not None:
            stretches.append(line["host_monotonic"] - since)
            since = None
    return stretches


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


def test_a_leader_idle_3_min_after_a_run_holds_for_no_fault_and_a_reset_lifts_its_holds(
    labs: Labs, tmp_path: Path
) -> None:
    router = labs.router("kiruna")
    experiment = write_experiment(tmp_path / "idle.toml")
    leader = labs.agent(
        LEADER, router, "--experiment", str(experiment), "--runs-dir", str(tmp_path / "runs")
    )
    leader.until(lambda line: line["mode"] == "waiting" and line["ready"]["platform"], 30, "ready")
    ctl("start", experiment, router.endpoint, "--run-id", "before-idle")
    done = leader.until(lambda line: line["mode"] == "done", RUN + 15, "the run done")
    lines = leader.lines()
    began = next(line for line in lines if line["mode"] == "running")
    print(f"\nheld {began['host_monotonic'] - lines[0]['host_monotonic']:.1f} s before its run")

    # Idle, every line read until IDLE s after the run (or the first held for a fault).
    end = done["host_monotonic"] + IDLE
    leader.until(
        lambda line: line["hold"] not in RUNS_OWN or line["host_monotonic"] >= end,
        IDLE + 30,
        f"{IDLE:g} s idle",
    )
    lines = leader.lines()
    faults = [(line["t_exec"], line["hold"]) for line in lines if line["hold"] not in RUNS_OWN]
    assert not faults, f"held for a fault it does not have (t_exec, hold): {faults[:3]}"
    for name in ("fix_restarts", "fix_restart_holds"):
        assert all(line["counters"].get(name, 0) == 0 for line in lines), name
    idle = [line for line in lines if line["host_monotonic"] >= done["host_monotonic"]]
    assert idle[-1]["host_monotonic"] >= end
    assert all(line["mode"] == "done" and line["hold"] == "done" for line in idle)
    # The mechanism was exercised: out of the camera's view long enough for the dead
    # reckoning to go far off, then seen again.
    stretches = out_of_view(idle)
    fixes = {k: v for k, v in idle[-1]["counters"].items() if k.startswith("fix_") and v}
    print(f"idle: out of view {[round(s, 1) for s in stretches]} s, then seen; {fixes}")
    assert max(stretches, default=0.0) >= OUT_OF_VIEW, stretches

    # A confirmed reset lifts the holds a reset lifts: done after the run, then aborted.
    reset_lifts(leader, experiment, router.endpoint, "done")
    ctl("abort", experiment, router.endpoint)
    leader.until(lambda line: line["hold"] == "aborted", 5, "held aborted")
    reset_lifts(leader, experiment, router.endpoint, "aborted")

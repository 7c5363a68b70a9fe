"""Every transition on a common instant, with real processes: ``fedlab ctl freeze``
then ``fedlab ctl resume`` across three agents in two labs, over the link emulator
(40 ms one way). Each agent applies the freeze (the resume) at the reference instant
ctl announced, so all freeze at the same run time and resume at the same one; the
figures come from each agent's status (its last transition applied) and recording."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from lifecycle import fedlab, runs_dir
from loopback import FOLLOWER, LEADER, Agent, Labs

from federation.fleet.launch import wait_for
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration

SECOND = "kiruna/geppetto"  # a follower in the leader's lab: its path to ctl is short
LOCKED = 25.0  # s: the agents start (slow on a busy host), then the estimate locks 1 s in
SYNC_WINDOW = "1"  # s: a transition needs a locked estimate, and this claim no more
AGREE = 0.001  # s: the run times at which the agents froze (resumed) agree within this


def write_three(path: Path) -> Path:
    """KNATTE leads in Kiruna; PINOCCHIO (Rome) and GEPPETTO (Kiruna) follow it."""
    follower = f'role = "follower"\nplatform = "pinocchio"\nfollow = "{LEADER}"\n'
    path.write_text(
        'name = "instants"\nduration = 60.0\nstart_delay = 1.5\n'
        "[maneuver]\nstill = 1.0\nduration = 10.0\namplitude_deg = 20.0\n"
        f'[[participants]]\nagent = "{LEADER}"\nrole = "leader"\nplatform = "knatte"\n'
        f'[[participants]]\nagent = "{FOLLOWER}"\n{follower}'
        f'[[participants]]\nagent = "{SECOND}"\n{follower}',
        encoding="utf-8",
    )
    return path


def locked(line: dict[str, Any]) -> bool:
    return bool((line.get("ready") or {}).get("reference_locked")) and line["mode"] == "waiting"


def applied(agents: dict[str, Agent], event: str) -> dict[str, dict[str, Any]]:
    """Each agent's ``event`` transition as its status says (bounded wait for all)."""
    for agent in agents.values():
        agent.until(
            lambda s: (s.get("transition") or {}).get("event") == event, timeout=10, what=event
        )
    return {who: agent.latest()["transition"] for who, agent in agents.items()}


def test_every_agent_freezes_and_resumes_at_the_same_run_time(labs: Labs, tmp_path: Path) -> None:
    pair = labs.pair(link=["--delay-ms", "40"])
    experiment = write_three(tmp_path / "exp.toml")
    at = {LEADER: pair.kiruna, FOLLOWER: pair.rome, SECOND: pair.kiruna}
    agents = {
        who: labs.agent(
            who, router, "--experiment", str(experiment), "--runs-dir", str(runs_dir(labs, who)),
            "--sync-window", SYNC_WINDOW,
        )
        for who, router in at.items()
    }  # fmt: skip
    for who in (FOLLOWER, SECOND):
        agents[who].until(locked, timeout=LOCKED, what="locked, waiting")
    # ctl in the leader's lab: its sync burst with the reference (20 exchanges) takes
    # a loopback round trip each, not the link's 80 ms; the commands reach PINOCCHIO
    # across the link, the slowest path, which the lead must cover.
    common = ("--experiment", str(experiment), "-e", pair.kiruna.endpoint, "--run-id", "instants")
    started, _ = fedlab("ctl", "start", *common)
    assert started.returncode == 0, started.stdout + started.stderr
    for agent in agents.values():
        agent.until(lambda s: s["mode"] == "running", timeout=10, what="running")

    figures: dict[str, dict[str, dict[str, Any]]] = {}
    for action, event in (("freeze", "frozen"), ("resume", "resumed")):
        done, took = fedlab("ctl", action, *common[:4])
        assert done.returncode == 0, done.stdout + done.stderr
        said = done.stdout + done.stderr
        assert f"{action} at reference time" in said and "slowest path: to" in said, said
        figures[event] = applied(agents, event)
        ats = {who: t["at"] for who, t in figures[event].items()}
        run_times = {who: t["run_time"] for who, t in figures[event].items()}
        spread = max(run_times.values()) - min(run_times.values())
        print(f"ctl {action} ({took:.1f} s):")
        for who in agents:
            print(
                f"  {who}: {event} at reference time {ats[who]:.6f} s, "
                f"run time {run_times[who]:.6f} s"
            )
        print(f"  run times agree within {spread * 1e3:.6f} ms")
        assert spread <= AGREE, figures[event]
        assert max(ats.values()) - min(ats.values()) <= AGREE, figures[event]
        assert all(not t["detail"] for t in figures[event].values()), figures[event]  # none late
    # Frozen and resumed at one run time: no run time passed while frozen.
    for who in agents:
        assert figures["resumed"][who]["run_time"] == pytest.approx(
            figures["frozen"][who]["run_time"], abs=1e-9
        )

    # Each recording says the same: its /control event at the instant, with the run time.
    # How late after the instant each applied it on its loop (its own clock, through its
    # estimate of the reference's): printed, not asserted, a wall-clock figure.
    offsets = {who: (a.peer(LEADER) or {}).get("offset", 0.0) for who, a in agents.items()}
    for agent in agents.values():
        agent.stop()
    for who in agents:
        stem = who.replace("/", "-")
        mcap = runs_dir(labs, who) / "instants" / f"{stem}.mcap"
        assert wait_for(mcap.exists, timeout=10), f"{who}: no recording"
        control = read_messages(mcap)["/control"]
        for event in ("frozen", "resumed"):
            (recorded,) = [e for e in control if e["event"] == event]
            assert recorded["t_sim"] == figures[event][who]["at"], (who, recorded)
            assert recorded["run_time"] == pytest.approx(figures[event][who]["run_time"], abs=1e-9)
            late = recorded["t_exec"] + offsets[who] - recorded["t_sim"]
            print(f"  {who}: {event} on its loop {late * 1e3:.2f} ms after the instant")

"""Helpers of the run lifecycle and collection tests: an experiment file, agents that
take part in it with their own runs folder, and ``fedlab`` commands as processes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from loopback import FOLLOWER, LEADER, Agent, LabPair, Labs

__all__ = ["QUICK_LOCK", "as_json", "fedlab", "participants", "runs_dir", "write_experiment"]

QUICK_LOCK = ("--sync-window", "2")
"""``fedlab agent`` arguments that lock the reference clock's estimate 2 s after the
first exchange rather than after the paper's 10 s sync phase: a start needs a locked
estimate, and a test of the run's lifecycle needs no more than that."""


def write_experiment(
    path: Path, duration: float, name: str = "lifecycle", more: str = "", raw: str | None = None
) -> Path:
    """A two-lab experiment (KNATTE leads, PINOCCHIO follows) of ``duration`` s;
    ``more``: top-level TOML lines added before its tables; ``raw`` (LAB/NAME): a third
    participant, a follower of the leader without latency compensation (it tracks the
    heading as received)."""
    third = (
        f'[[participants]]\nagent = "{raw}"\nrole = "follower"\nplatform = "pinocchio"\n'
        f'follow = "{LEADER}"\nlatency_compensation = false\n'
        if raw is not None
        else ""
    )
    path.write_text(
        f'name = "{name}"\nduration = {duration}\nstart_delay = 1.5\n{more}'
        "[maneuver]\nstill = 1.0\nduration = 10.0\namplitude_deg = 20.0\n"
        f'[[participants]]\nagent = "{LEADER}"\nrole = "leader"\nplatform = "knatte"\n'
        f'[[participants]]\nagent = "{FOLLOWER}"\nrole = "follower"\nplatform = "pinocchio"\n'
        f'follow = "{LEADER}"\n{third}',
        encoding="utf-8",
    )
    return path


def runs_dir(labs: Labs, who: str) -> Path:
    """Each agent's own runs folder, as on its own host."""
    return labs.tmp / f"host-{who.split('/')[0]}" / "runs"


def participants(
    labs: Labs, pair: LabPair, experiment: Path, *extra: str, raw: str | None = None
) -> dict[str, Agent]:
    """KNATTE on Kiruna's router and PINOCCHIO on Rome's, both in ``experiment``; with
    ``raw`` (a Rome agent, see :func:`write_experiment`) that one too, on Rome's."""
    placed = [(LEADER, pair.kiruna), (FOLLOWER, pair.rome)]
    if raw is not None:
        placed.append((raw, pair.rome))
    return {
        who: labs.agent(
            who, at, "--experiment", str(experiment), "--runs-dir", str(runs_dir(labs, who)), *extra
        )
        for who, at in placed
    }


def fedlab(*args: str, timeout: float = 90) -> tuple[subprocess.CompletedProcess[str], float]:
    """Run ``fedlab ARGS`` to its end; the finished process and its duration (s)."""
    start = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "federation", *args],
        capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    return done, time.monotonic() - start


def as_json(done: subprocess.CompletedProcess[str]) -> Any:
    """A ``--json`` command's output."""
    return json.loads(done.stdout)

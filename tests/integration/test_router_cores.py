"""``fedlab router --cpus``: a real router process whose every thread (Zenoh's
included) runs on the core asked for; a core it may not use, or a list that is
not one, fails at start naming the flag."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from loopback import Labs

from federation.fleet.launch import wait_for
from federation.runtime.cpus import parse_cpus, usable_cpus

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")


def _threads_cores(pid: int) -> dict[str, frozenset[int]]:
    """Each thread's name and the cores it may run on, from /proc."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        lines = (task / "status").read_text().splitlines()
        status = dict(line.split(":\t", 1) for line in lines if ":\t" in line)
        cores = parse_cpus(status["Cpus_allowed_list"].strip())
        out[f"{status['Name'].strip()}#{task.name}"] = cores
    return out


def test_a_router_on_a_core_of_its_own_runs_every_thread_there(labs: Labs) -> None:
    core = max(usable_cpus())
    router = labs.router("kiruna", "--cpus", str(core))
    assert wait_for(lambda: "up (zid" in router.log(), 30), router.log()
    pid = labs.fleet.procs[router.name].pid
    threads = _threads_cores(pid)
    assert len(threads) > 3, threads  # Zenoh's runtime threads, not only the interpreter's
    assert set(threads.values()) == {frozenset({core})}, threads
    free = labs.router("rome", connect=router)  # without --cpus: where the kernel pleases
    assert wait_for(lambda: "up (zid" in free.log(), 30), free.log()
    assert set(_threads_cores(labs.fleet.procs[free.name].pid).values()) == {usable_cpus()}


@pytest.mark.parametrize(
    ("cpus", "says"),
    [("4096", "--cpus: core 4096 is not one this process may use"),
     ("x", "argument --cpus: 'x' in 'x' is not a core or a range of cores")],
)  # fmt: skip
def test_a_router_asked_for_cores_it_cannot_have_fails_at_start(cpus: str, says: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "federation", "router", "--lab", "kiruna",
         "-l", "tcp/127.0.0.1:0", "--cpus", cpus],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert done.returncode == 2, done
    assert says in done.stderr, done.stderr

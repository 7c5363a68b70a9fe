"""``fedlab router --cpus`` and ``fedlab agent --cpus``: real processes whose every
thread (Zenoh's included) runs on the core asked for; a core the process may not
use, or a list that is not one, fails at start naming the flag."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from loopback import Labs

from federation.fleet.launch import wait_for
from federation.runtime.cpus import format_cpus, parse_cpus, usable_cpus

pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="Linux, with two cores to tell a pinned process from a free one",
)


def _threads_cores(pid: int) -> dict[str, frozenset[int]]:
    """Each thread's name and the cores it may run on, from /proc."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            lines = (task / "status").read_text().splitlines()
        except (FileNotFoundError, ProcessLookupError):  # the thread ended meanwhile
            continue
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
    # An agent on the other cores, as docs/deploy.md says (every thread of it too).
    others = usable_cpus() - {core}
    agent = labs.agent("kiruna/knatte", router, "--cpus", format_cpus(others), role="leader")
    agent.wait_status(30)
    agent_threads = _threads_cores(labs.fleet.procs[agent.name].pid)
    assert len(agent_threads) > 3 and set(agent_threads.values()) == {others}, agent_threads


@pytest.mark.parametrize(
    ("cpus", "says"),
    [("8000", "--cpus: core 8000 not among those this process may use"),
     ("x", "argument --cpus: 'x' is not a core or a range of cores")],
)  # fmt: skip
@pytest.mark.parametrize(
    "command",
    [["router", "--lab", "kiruna", "-l", "tcp/127.0.0.1:0"],
     ["agent", "--lab", "kiruna", "--name", "knatte", "--role", "leader", "-e", "tcp/127.0.0.1:9"]],
)  # fmt: skip
def test_cores_it_cannot_have_fail_at_start_naming_the_flag(
    command: list[str], cpus: str, says: str
) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "federation", *command, "--cpus", cpus],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert done.returncode == 2, done
    assert says in done.stderr, done.stderr

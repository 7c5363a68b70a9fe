"""Keeping a process to some cores: the list's syntax, the refusals, and that every
thread (started before or after) ends up on the cores asked for (a real child process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from federation.fleet.launch import Fleet, wait_for
from federation.runtime.cpus import format_cpus, parse_cpus, pin_process, usable_cpus
from schemas.config import ConfigError

linux = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")
# Pinning to one core of two or more: on a one-core host the mask would not change.
two_cores = pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs two cores to tell a pinned process from a free one",
)


@pytest.mark.parametrize(
    ("text", "cpus"),
    [("0", {0}), ("2-3", {2, 3}), ("0,2-3", {0, 2, 3}), (" 1 , 4-5 ", {1, 4, 5}), ("3-3", {3})],
)
def test_a_list_of_cores_reads_as_taskset_takes_it(text: str, cpus: set[int]) -> None:
    assert parse_cpus(text) == cpus
    assert parse_cpus(format_cpus(cpus)) == cpus


def test_format_joins_runs() -> None:
    assert format_cpus({0, 1, 2, 5, 7, 8}) == "0-2,5,7-8"
    assert format_cpus([3]) == "3"
    assert format_cpus([2, 1, 1, 2, 9]) == "1-2,9"  # unsorted, repeated


@pytest.mark.parametrize(
    ("text", "says"),
    [("", "'' is not a core"), ("a", "'a' is not a core"), ("-1", "'-1' is not a core"),
     ("0,,1", "'' in '0,,1' is not a core"), ("1-x", "'1-x' is not a core"),
     ("1_0", "'1_0' is not a core"), ("0-8:2", "'0-8:2' is not a core"),
     ("3-1", "'3-1': cores go from 0 to 8191"), ("0,2-99999", "'2-99999' in '0,2-99999': cores")],
)  # fmt: skip
def test_a_bad_list_names_its_bad_part(text: str, says: str) -> None:
    with pytest.raises(ValueError) as raised:
        parse_cpus(text)  # a huge range is refused before any set is built
    assert says in str(raised.value)


@linux
def test_a_core_this_process_may_not_use_is_refused_naming_the_flag() -> None:
    usable = usable_cpus()
    absent = max(usable) + 1000
    with pytest.raises(ConfigError, match=r"--cpus: core \d+ not among those") as e:
        pin_process({absent}, "--cpus")
    assert format_cpus(usable) in str(e.value)  # says which it may use
    with pytest.raises(ConfigError, match="--cpus: no core given"):
        pin_process(set(), "--cpus")
    assert usable_cpus() == usable  # nothing changed


_CHILD = textwrap.dedent(
    """
    import json, os, sys, threading
    from federation.runtime.cpus import pin_process
    seen = {}
    started = threading.Event(); go = threading.Event()
    def before():
        started.set(); go.wait(10)
        seen["before"] = sorted(os.sched_getaffinity(0))
    t = threading.Thread(target=before); t.start(); started.wait(10)
    pin_process({int(sys.argv[1])}, "--cpus")
    go.set(); t.join()
    u = threading.Thread(target=lambda: seen.setdefault("after", sorted(os.sched_getaffinity(0))))
    u.start(); u.join()
    seen["main"] = sorted(os.sched_getaffinity(0))
    print(json.dumps(seen))
    """
)


@two_cores
def test_every_thread_runs_on_the_cores_pinned_also_one_started_before() -> None:
    core = max(usable_cpus())
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(core)], capture_output=True, text=True, timeout=60,
        check=True,
    )  # fmt: skip
    assert json.loads(done.stdout) == {"before": [core], "after": [core], "main": [core]}


_REPORT = (
    "import os, threading; "
    "t = threading.Thread(target=lambda: print('cores', sorted(os.sched_getaffinity(0)))); "
    "t.start(); t.join()"
)


@two_cores
def test_a_fleet_process_started_on_cores_runs_every_thread_there(tmp_path: Path) -> None:
    core = max(usable_cpus())
    with Fleet(tmp_path) as fleet:
        proc = fleet.spawn("child", [sys.executable, "-c", _REPORT], cpus={core})
        assert wait_for(lambda: proc.poll() is not None, 30)
        assert proc.returncode == 0
        assert fleet.log_path("child").read_text().strip() == f"cores [{core}]"
        free = fleet.spawn("free", [sys.executable, "-c", _REPORT])  # no cores: as it may
        assert wait_for(lambda: free.poll() is not None, 30)
        assert fleet.log_path("free").read_text().strip() == f"cores {sorted(usable_cpus())}"
        for cpus in (set(), {max(usable_cpus()) + 1000}):  # refused here, nothing started
            with pytest.raises(ValueError, match=r"process 'none': cores .* not among those"):
                fleet.spawn("none", [sys.executable, "-c", "pass"], cpus=cpus)
        assert "none" not in fleet.procs

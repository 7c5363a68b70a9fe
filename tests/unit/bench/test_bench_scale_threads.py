"""The scale bench's split of the workers' CPU by thread (read from /proc)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

from federation.bench.scale import _fields_moved, _per_thread, _thread_cpu


def test_a_named_thread_that_burns_cpu_shows_under_its_folded_name() -> None:
    # A name with digits, a parenthesis and spaces, as /proc's stat line shows it.
    before: dict[int, tuple[str, float, float]] = {}
    after: dict[int, tuple[str, float, float]] = {}

    def burn() -> None:
        nonlocal before, after
        with open(f"/proc/self/task/{threading.get_native_id()}/comm", "w") as comm:
            comm.write("rx-1) a (b")
        before = _thread_cpu(os.getpid())
        start = time.thread_time()
        while time.thread_time() - start < 0.3:  # bounded by this thread's own CPU time
            sum(range(10_000))  # the interpreter's work between two clock readings
        after = _thread_cpu(os.getpid())

    worker = threading.Thread(target=burn)
    worker.start()
    worker.join(timeout=60)
    split = _per_thread([before], [after], 1.0)
    assert split.get("rx-#) a (b", 0.0) >= 200.0, split  # ms in one "agent-second"
    kernel = _per_thread([before], [after], 1.0, kernel=True).get("rx-#) a (b", 0.0)
    assert kernel < 0.5 * split["rx-#) a (b"], (kernel, split)  # a loop of the interpreter's


def test_a_process_that_has_ended_reads_as_no_threads() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    assert _thread_cpu(proc.pid) == {}


def test_per_thread_sums_the_workers_by_name_per_agent_second() -> None:
    # (name, CPU seconds, of which in the kernel)
    before = [{1: ("python", 1.0, 0.2), 2: ("rx-#", 0.5, 0.1)}, {7: ("python", 2.0, 0.5)}]
    after = [{1: ("python", 1.4, 0.3), 2: ("rx-#", 0.9, 0.3), 3: ("tx-#", 0.1, 0.1)},
             {7: ("python", 2.2, 0.5), 8: ("rx-#", 0.3, 0.0)}]  # fmt: skip
    # 10 agents for 2 s: 20 agent-seconds; threads 3 and 8 started meanwhile (from 0)
    split = _per_thread(before, after, 20.0)
    assert split == {"python": 30.0, "rx-#": 35.0, "tx-#": 5.0}
    kernel = _per_thread(before, after, 20.0, kernel=True)
    assert kernel == {"python": 5.0, "rx-#": 10.0, "tx-#": 5.0}


def test_each_thread_time_that_moved_may_overstate_by_a_tick() -> None:
    # (name, CPU seconds, of which in the kernel): user and system times moved or not
    before = [{1: ("python", 1.0, 0.2), 2: ("rx-#", 0.5, 0.1), 4: ("idle", 0.3, 0.1)}]
    after = [{1: ("python", 1.4, 0.3), 2: ("rx-#", 0.6, 0.1), 3: ("tx-#", 0.01, 0.0),
              4: ("idle", 0.3, 0.1)}]  # fmt: skip
    # python: both moved; rx-#: user only; tx-# (new): user only; idle: neither
    assert _fields_moved(before, after) == 4
    assert _fields_moved(after, after) == 0


def test_a_thread_that_ended_takes_nothing_from_others_of_its_name() -> None:
    # rx-1 (tid 2) ran 0.29 s and ended; rx-2 (tid 3) started and ran 0.04 s.
    before = [{1: ("python", 1.0, 0.1), 2: ("rx-#", 0.29, 0.1)}]
    after = [{1: ("python", 1.0, 0.1), 3: ("rx-#", 0.04, 0.01)}]
    assert _per_thread(before, after, 1.0) == {"rx-#": 40.0}
    assert _per_thread(before, after, 1.0, kernel=True) == {"rx-#": 10.0}


def test_a_thread_in_system_calls_shows_its_time_in_the_kernel() -> None:
    # Large reads of /dev/zero: the kernel fills the buffer, the interpreter does little.
    before: dict[int, tuple[str, float, float]] = {}
    after: dict[int, tuple[str, float, float]] = {}

    def read_zeros() -> None:
        nonlocal before, after
        with open(f"/proc/self/task/{threading.get_native_id()}/comm", "w") as comm:
            comm.write("reader")
        before = _thread_cpu(os.getpid())
        start = time.thread_time()
        with open("/dev/zero", "rb", buffering=0) as zeros:
            while time.thread_time() - start < 0.3:  # bounded by this thread's own CPU time
                zeros.read(1 << 20)
        after = _thread_cpu(os.getpid())

    worker = threading.Thread(target=read_zeros)
    worker.start()
    worker.join(timeout=60)
    total = _per_thread([before], [after], 1.0).get("reader", 0.0)
    kernel = _per_thread([before], [after], 1.0, kernel=True).get("reader", 0.0)
    assert total >= 200.0 and kernel >= 0.5 * total, (kernel, total)

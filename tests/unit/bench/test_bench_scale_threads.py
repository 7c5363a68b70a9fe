"""The scale bench's split of the workers' CPU by thread (read from /proc)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from federation.bench.scale import _per_thread, _thread_cpu


def test_a_thread_that_burns_cpu_shows_in_its_process_reading() -> None:
    before = _thread_cpu(os.getpid())
    start = time.thread_time()
    while time.thread_time() - start < 0.3:  # bounded by this thread's own CPU time
        pass
    after = _thread_cpu(os.getpid())
    spent = sum(after.values()) - sum(before.values())
    assert spent >= 0.2, (before, after)
    assert not any(ch.isdigit() for name in after for ch in name)  # rx-0, rx-1 -> rx-#


def test_a_process_that_has_ended_reads_as_no_threads() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    assert _thread_cpu(proc.pid) == {}


def test_per_thread_sums_the_workers_by_name_per_agent_second() -> None:
    before = [{"python": 1.0, "rx-#": 0.5}, {"python": 2.0}]
    after = [{"python": 1.4, "rx-#": 0.9, "tx-#": 0.1}, {"python": 2.2, "rx-#": 0.3}]
    # 10 agents for 2 s: 20 agent-seconds
    split = _per_thread(before, after, 20.0)
    assert split == {"python": 30.0, "rx-#": 35.0, "tx-#": 5.0}

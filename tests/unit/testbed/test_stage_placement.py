"""Where the testbed's packet stage runs (federation/testbed/bed.py): first among
the host's processes. No namespace is made here."""

from __future__ import annotations

import os
import subprocess
import sys

from federation.testbed.bed import STAGE_NICE, raise_priority


def test_the_stage_priority_is_real_time_or_the_highest_niceness_it_may_have() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        got = raise_priority(child.pid)
        if got == "fifo":
            assert os.sched_getscheduler(child.pid) == os.SCHED_FIFO
        elif got == "nice":
            assert os.getpriority(os.PRIO_PROCESS, child.pid) == STAGE_NICE
        else:
            assert got == "normal" and os.geteuid() != 0  # root always gets one of the two
    finally:
        child.kill()
        child.wait()

"""Where the testbed's packet stage runs (federation/testbed/bed.py): first among
the host's processes, its counters written to memory and kept with the run on
close. No namespace is made here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from federation.testbed import bed
from federation.testbed.bed import STAGE_NICE, Testbed, raise_priority


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


def test_the_stage_counters_live_in_memory_and_are_kept_with_the_run(tmp_path: Path) -> None:
    testbed = Testbed(tmp_path / "run")
    stats = testbed.stats_path
    assert not stats.is_relative_to(tmp_path)
    if bed._MEMORY_DIR is not None:
        assert stats.is_relative_to(bed._MEMORY_DIR)
    stats.write_text(json.dumps({"forward": {"delivered": 3}}))
    testbed.close()
    assert json.loads((tmp_path / "run" / "stage.json").read_text())["forward"]["delivered"] == 3
    assert not stats.parent.exists()
    testbed.close()  # idempotent: nothing left to copy or remove

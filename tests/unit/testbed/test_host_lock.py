"""One testbed at a time on a host: the lock a testbed holds while it runs."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from federation.testbed.bed import TestbedError, _take_host_lock


def test_a_second_testbed_waits_for_the_first_and_names_it(tmp_path: Path) -> None:
    path = tmp_path / "testbed.lock"
    first = _take_host_lock(path, wait=0.0)
    began = time.monotonic()
    with pytest.raises(TestbedError, match=rf"held {path} for 0.3 s \(pid {os.getpid()}\)"):
        _take_host_lock(path, wait=0.3)
    assert time.monotonic() - began >= 0.3  # it waited its bound, then said who holds it
    first.close()  # the first testbed ends: the next one runs
    second = _take_host_lock(path, wait=0.0)
    assert path.read_text() == f"{os.getpid()}\n"
    second.close()

"""The packet stage's counters file (federation/link/tun.py): written on a thread of
its own, so a slow disk never holds back the forwarding loop."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

from federation.link.tun import _StatsWriter


def test_an_offer_returns_while_a_write_is_stuck_and_the_file_ends_final(
    tmp_path: Path,
) -> None:
    path = tmp_path / "stage.json"
    writer = _StatsWriter(path)
    writing, unstick = threading.Event(), threading.Event()
    real = writer._write

    def stuck(snapshot: dict[str, Any]) -> None:  # a disk that takes its time
        writing.set()
        assert unstick.wait(10.0)
        real(snapshot)

    writer._write = stuck  # type: ignore[method-assign]
    writer.offer({"n": 1})
    assert writing.wait(5.0)
    began = time.monotonic()
    for n in range(2, 100):  # the loop's offers while the write hangs
        writer.offer({"n": n})
    assert time.monotonic() - began < 0.5
    writer._write = real  # type: ignore[method-assign]
    unstick.set()
    writer.close({"n": "final"})
    assert json.loads(path.read_text()) == {"n": "final"}
    assert not path.with_name("stage.json.tmp").exists()


def test_offers_made_during_a_write_collapse_into_the_newest(tmp_path: Path) -> None:
    path = tmp_path / "stage.json"
    writer = _StatsWriter(path)
    written: list[Any] = []
    gate = threading.Event()

    def record(snapshot: dict[str, Any]) -> None:
        written.append(snapshot["n"])
        gate.wait(5.0)

    writer._write = record  # type: ignore[method-assign]
    writer.offer({"n": 0})
    deadline = time.monotonic() + 5.0
    while not written and time.monotonic() < deadline:  # bounded: the first write begins
        time.sleep(0.01)
    for n in range(1, 10):
        writer.offer({"n": n})
    gate.set()
    deadline = time.monotonic() + 5.0
    while len(written) < 2 and time.monotonic() < deadline:  # bounded: the next write
        time.sleep(0.01)
    writer.close({"n": "final"})
    assert written == [0, 9, "final"]

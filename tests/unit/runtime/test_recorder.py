"""MCAP recording: buffered, written by one thread per process, nothing lost at close."""

from __future__ import annotations

import threading
from pathlib import Path

from federation.fleet.launch import wait_for
from federation.runtime.recorder import Recorder, read_messages


def writers() -> int:
    return sum(1 for t in threading.enumerate() if t.name == "recorder")


def test_recorders_share_one_writer_and_lose_nothing_at_close(tmp_path: Path) -> None:
    assert wait_for(lambda: writers() == 0, timeout=2)  # none left by another test
    recorders = [Recorder(tmp_path / f"a{i}.mcap", f"lab/a{i}") for i in range(16)]
    try:
        assert writers() == 1
        for i, rec in enumerate(recorders):
            for k in range(100):
                rec.record("/pose/sent", {"t_exec": float(k), "host_monotonic": float(i)})
            rec.record("/truth", {"t_exec": 0.0})  # a channel recorded too
    finally:
        for rec in recorders:
            rec.close()
    for i in range(16):
        sent = read_messages(tmp_path / f"a{i}.mcap", ["/pose/sent"])["/pose/sent"]
        assert [m["t_exec"] for m in sent] == [float(k) for k in range(100)]
        assert {m["host_monotonic"] for m in sent} == {float(i)}
    assert wait_for(lambda: writers() == 0, timeout=2)  # gone with the last recorder


def test_unrecorded_channels_are_skipped_and_a_full_buffer_counts_drops(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "x.mcap", "lab/x", channels=["/status"], capacity=3)
    for k in range(5):
        rec.record("/pose/sent", {"t_exec": float(k)})
    rec.close()
    assert rec.dropped == 0 and rec.written == 0
    rec = Recorder(tmp_path / "y.mcap", "lab/y", capacity=3)
    with rec._write_lock:  # hold the writer off: the buffer fills
        for k in range(5):
            rec.record("/status", {"agent": "lab/y", "t_exec": float(k)})
    rec.close()
    assert rec.dropped == 2 and rec.written == 3
    rec.close()  # twice is harmless

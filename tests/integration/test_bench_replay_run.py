"""``fedlab bench replay``'s machinery with real processes on loopback, on a short
maneuver (3 s, 20 deg) and a 1 s sync window rather than the paper's: a router, the
leader, the follower behind the 40 ms link, the run, the fresh follower against the
leader's replay, both RMS errors, their ratio, the poses counted (as the recordings
hold them), and the exit status the bound gives it;
and a repeat that fails (an agent not ready in time) is named, exits 1, and leaves no
process behind.

The bound itself (replayed within 1.5 times live) is a claim about the host's time: it
holds while the ghost's poses flow with no gap, and beside the parallel suite a starved
process left a 3 s maneuver's replayed error at 2.03 times its live one. It is asserted
where the cores are free, by ``test_replay.py`` in the timing pass, and by the
committed benchmark (``benchmarks/replay-paper.json``). So is the poses' full 20 Hz: beside
the parallel suite a stall once left 49 of the window's 56."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from lifecycle import fedlab

from federation.bench import replay
from federation.report import tracking
from federation.runtime.replayfile import Recording

pytestmark = pytest.mark.integration


def running_under(folder: Path) -> list[str]:
    """Command lines of this machine's processes that name ``folder`` (what the bench
    started there and did not stop)."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:  # ended meanwhile
            continue
        if str(folder) in cmdline:
            found.append(f"{pid}: {cmdline}")
    return found


def test_the_bench_flies_live_then_against_the_replay(tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    done, _ = fedlab(
        "bench", "replay", "--repeats", "1", "--maneuver-seconds", "3", "--sync-window", "1",
        "--work-dir", str(tmp_path / "work"), "--json-out", str(out), timeout=150,
    )  # fmt: skip
    assert out.exists(), done.stdout + done.stderr
    result = json.loads(out.read_text())
    (r,) = result["repeats"]
    assert "ratio" in r, done.stdout + done.stderr  # the repeat ran to its end
    # Exit 0 when the ratio is within the bound; 1, naming the ratio, when it is not.
    within = r["ratio"] <= replay.BOUND
    assert done.returncode == (0 if within else 1), done.stdout + done.stderr
    if not within:
        assert f"repeat 0: ratio {r['ratio']:.3f} exceeds {replay.BOUND:g}" in done.stderr
    assert result["command"] == (
        f"fedlab bench replay --repeats 1 --maneuver-seconds 3 --sync-window 1 --json-out {out}"
    )
    assert result["link"]["delay_ms"] == 40.0
    print(
        f"live {r['rms_live_deg']:.3f} deg, replayed {r['rms_replayed_deg']:.3f} deg, "
        f"ratio {r['ratio']:.3f}, poses {r['poses']}"
    )
    assert r["rms_live_deg"] > 0 and r["rms_replayed_deg"] > 0
    assert r["ratio"] == pytest.approx(r["rms_replayed_deg"] / r["rms_live_deg"])
    assert r["ghost_exit"] == 0
    assert (r["window_s"], r["run_s"]) == ([0.7, 3.5], 4.0)
    assert result["summary"]["repeats_done"] == 1
    # The poses the bench counts are those each recording holds, counted again here from
    # the files: the follower's inside the window it scores, and every agent's in its run.
    # At least tracking.MIN_POSES in the window, or the bench refuses the repeat. That
    # they come at the full 20 Hz is a claim about the host's time, asserted on the same
    # agents and recordings where the cores are free (test_replay.py, in the timing pass).
    work = tmp_path / "work" / "repeat-0"
    recordings = {
        "leader": ("live-kiruna-knatte", replay.LEADER),
        "follower_live": ("live-rome-pinocchio", replay.FOLLOWER),
        "follower_replayed": ("replayed-rome-pinocchio", replay.FOLLOWER),
    }
    assert set(r["recorded"]) == set(recordings)
    times = {}
    for who, (name, agent) in recordings.items():
        assert (work / f"{name}.mcap").stat().st_size > 0
        poses = Recording(work / f"{name}.mcap", agent).poses()
        times[who] = [p.run_time for p in poses if p.run_time is not None]
        reached = r["recorded"][who]  # each flew the whole run
        assert reached == {"poses": len(times[who]), "run_time_reached_s": max(times[who])}
        assert reached["run_time_reached_s"] > 3.8, (who, reached)
    for scored, who in (("live", "follower_live"), ("replayed", "follower_replayed")):
        inside = sum(0.7 <= t <= 3.5 for t in times[who])
        assert r["poses"][scored] == inside >= tracking.MIN_POSES, (scored, inside)
    assert not running_under(tmp_path)


def test_a_repeat_that_fails_is_named_and_stops_every_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # No agent can lock its reference clock in 0.3 s: the first wait fails.
    monkeypatch.setattr(replay, "READY_TIMEOUT", 0.3)
    result = replay.run(1, tmp_path, maneuver_seconds=4.0, sync_window=2.0)
    (r,) = result["repeats"]
    assert "live-kiruna-knatte: ready to start not reached within 0.3 s" in r["error"]
    (why,) = replay.failures(result)
    assert why.startswith("repeat 0 failed: live-kiruna-knatte: ready to start not reached")
    assert result["summary"] == {"repeats_done": 0, "repeats_failed": 1}
    assert not running_under(tmp_path)
    # The router and the link were started too, and stopped: their logs say they ran.
    logs = tmp_path / "repeat-0" / "logs"
    assert {p.stem for p in logs.glob("*.log")} >= {"router", "link", "live-kiruna-knatte"}

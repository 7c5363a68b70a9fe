"""A run flown in segments (an agent killed, started again, rejoined): each segment in
files of its own, one manifest listing every segment whichever is finalized last, and
the first segment recovered even when the second finished first
(federation/runtime/runs.py, runfolder.py)."""

from __future__ import annotations

import os
from pathlib import Path

from federation.core.channels import segment_stem
from federation.runtime.collect import manifest_name, recover_runs, unfinished_runs
from federation.runtime.recorder import Recorder
from federation.runtime.runfolder import listed
from federation.runtime.runs import RunRecording
from schemas.messages import Manifest

AGENT = "kiruna/knatte"
STEM = "kiruna-knatte"


def _segment(runs: Path, segment: int, finish: bool = True) -> RunRecording:
    run = RunRecording(runs, "r1", AGENT, None, "{}", None, {"segment": segment}, segment=segment)
    for k in range(50):
        run.record("/status", {"agent": AGENT, "run_time": float(k), "mode": "running"})
    run.status_line('{"agent": "kiruna/knatte"}')
    if finish:
        run.finish(wait=True)
    return run


def _killed(runs: Path) -> Path:
    """A first segment cut by a kill: an MCAP with no summary, no manifest."""
    path = runs / "r1" / f"{STEM}.mcap"
    rec = Recorder(path, AGENT)
    for k in range(50):
        rec.record("/status", {"agent": AGENT, "run_time": float(k), "mode": "running"})
    rec.flush()
    data = path.read_bytes()
    rec.close()
    path.write_bytes(data)  # as the kill left it: nothing after the last flush
    return path


def test_segment_stems() -> None:
    assert segment_stem(AGENT, 1) == STEM
    assert segment_stem(AGENT, 2) == f"{STEM}.seg2"


def test_one_manifest_lists_every_segment_whichever_finishes_last(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _segment(runs, 1)
    second = _segment(runs, 2)
    assert second.mcap.name == f"{STEM}.seg2.mcap"
    names = listed(runs / "r1", AGENT)
    assert names == {f"{STEM}.mcap", f"{STEM}.jsonl", f"{STEM}.seg2.mcap", f"{STEM}.seg2.jsonl"}
    manifest = Manifest.model_validate_json((runs / "r1" / manifest_name(STEM)).read_text())
    assert manifest.agent == AGENT and manifest.run_id == "r1"


def test_a_killed_first_segment_is_recovered_after_the_second_finished(tmp_path: Path) -> None:
    # The agent rejoined before its recovery could run (it waits while a run records):
    # the second segment's manifest must not hide the first, unfinished, segment.
    runs = tmp_path / "runs"
    _killed(runs)
    _segment(runs, 2)
    assert f"{STEM}.mcap" not in (listed(runs / "r1", AGENT) or set())
    assert unfinished_runs(runs, AGENT) == [runs / "r1"]
    result = recover_runs(runs, AGENT)
    assert set(result.recovered) == {"r1"} and not result.failed
    names = listed(runs / "r1", AGENT)
    assert names is not None
    assert {f"{STEM}.mcap", f"{STEM}.seg2.mcap", f"{STEM}.seg2.jsonl"} <= names
    assert f"{STEM}.incomplete.json" in names  # the first segment's, recovered
    assert unfinished_runs(runs, AGENT) == []


def test_a_second_segment_cut_short_says_so_beside_its_own_files(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    run = RunRecording(runs, "r1", AGENT, None, "{}", None, None, max_mb=1, segment=2)
    for _ in range(30):  # past its 1 MiB
        for k in range(500):
            pad = os.urandom(60).hex()  # compressible, but not to nothing
            run.record("/pose/received", {"agent": "rome/p", "t": float(k), "pad": pad})
        run.recorder.flush()
    run.finish(wait=True)
    assert run.recorder.over_budget > 0
    assert (runs / "r1" / f"{STEM}.seg2.incomplete.json").exists()
    assert not (runs / "r1" / f"{STEM}.incomplete.json").exists()

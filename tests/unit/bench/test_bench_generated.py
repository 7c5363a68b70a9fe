"""federation/bench/generated.py without a testbed: which recording a run is scored
from (only a finished one), when a run counts as over, and what the agents are given."""

from __future__ import annotations

import json
from pathlib import Path

from federation.bench import generated
from federation.core import paper


def test_a_recording_counts_once_its_manifest_is_written(tmp_path: Path) -> None:
    folder = tmp_path / "pinocchio" / "run-1"
    folder.mkdir(parents=True)
    (folder / "rome-pinocchio.mcap").write_bytes(b"")  # still being written
    assert generated.recording(tmp_path, "pinocchio") is None
    assert not generated._all_recorded(tmp_path)
    (folder / "rome-pinocchio.manifest.json").write_text("{}")
    assert generated.recording(tmp_path, "pinocchio") == folder / "rome-pinocchio.mcap"
    assert not generated._all_recorded(tmp_path)  # the leader's is not there
    leader = tmp_path / "knatte" / "run-1"
    leader.mkdir(parents=True)
    (leader / "kiruna-knatte.manifest.json").write_text("{}")
    assert generated._all_recorded(tmp_path)


def test_the_run_is_over_when_every_agent_says_done(tmp_path: Path) -> None:
    status = {name: tmp_path / f"{name}.jsonl" for name in ("knatte", "pinocchio")}
    assert not generated._all_done(status)  # no line yet
    for path in status.values():
        path.write_text(json.dumps({"mode": "running"}) + "\n")
    assert not generated._all_done(status)
    status["knatte"].write_text(json.dumps({"mode": "done"}) + "\n")
    assert not generated._all_done(status)
    status["pinocchio"].write_text(json.dumps({"mode": "done"}) + "\n")
    assert generated._all_done(status)


def test_the_agents_settings_are_the_bench_agents(tmp_path: Path) -> None:
    settings = generated.agent_settings()
    assert settings["pinocchio"]["clock_offset"] == paper.CLOCK_OFFSET
    assert {s["status_period"] for s in settings.values()} == {0.5}

"""``fedlab merge`` after a short real two-lab run: the merged file reads with the mcap
library and, read back from it alone, the follower's guidance reference trails the
leader's sent heading as the report says from the per-agent files (within 1 ms); and
``fedlab report`` made from the merged file equals the one made from the per-agent
files, summary.json compared field by field (every field but ``source``, which names
the files read)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from lifecycle import QUICK_LOCK, fedlab, participants, runs_dir, write_experiment
from loopback import FOLLOWER, LEADER, Labs
from mcap.reader import make_reader

from federation.fleet.launch import wait_for
from federation.report.analysis import best_shift
from federation.report.merge import MERGE_METADATA

pytestmark = pytest.mark.integration


def test_a_merged_run_gives_the_reports_separation(labs: Labs, tmp_path: Path) -> None:
    pair = labs.pair(link=False)
    experiment = write_experiment(tmp_path / "exp.toml", 5)
    agents = participants(labs, pair, experiment, *QUICK_LOCK)
    agents[FOLLOWER].until(lambda s: (s.get("ready") or {}).get("reference_locked"), timeout=25)
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "merged",
        "--max-bound", "0.05", "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    for agent in agents.values():
        agent.until(lambda s: s["mode"] == "done", timeout=20, what="done")
    run = tmp_path / "run"
    run.mkdir()
    for who in agents:
        folder, stem = runs_dir(labs, who) / "merged", who.replace("/", "-")
        assert wait_for((folder / f"{stem}.manifest.json").exists, timeout=10), who
        shutil.copy(folder / f"{stem}.mcap", run / f"{stem}.mcap")

    reported, _ = fedlab("report", str(run), "--out", str(tmp_path / "report"))
    assert reported.returncode == 0, reported.stdout + reported.stderr
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    expected = next(f for f in summary["followers"] if f["follower"] == FOLLOWER)
    merged, took = fedlab("merge", str(run))
    print(merged.stdout, f"merge took {took:.2f} s")
    assert merged.returncode == 0, merged.stdout + merged.stderr
    assert (run / "merged.layout.json").exists()
    _same_report_from_the_merged_file(run, summary, tmp_path / "report-merged")

    series: dict[str, list[tuple[float, dict[str, float]]]] = {}
    with (run / "merged.mcap").open("rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}[MERGE_METADATA]
        epoch, start = int(meta["epoch_ns"]), float(meta["reference_start_s"])
        topics = [f"/{LEADER}/pose/sent", f"/{LEADER}/reference", f"/{FOLLOWER}/reference"]
        for _schema, channel, message in reader.iter_messages(topics=topics):
            t = start + (message.log_time - epoch) / 1e9  # reference time, from log time
            series.setdefault(channel.topic, []).append((t, json.loads(message.data)))
    sent, lead_ref = series[f"/{LEADER}/pose/sent"], series[f"/{LEADER}/reference"]
    moving = [t for t, m in lead_ref if abs(m["rate_ref"]) > 1e-12]
    reference = series[f"/{FOLLOWER}/reference"]
    separation = best_shift(
        [t for t, _ in reference], np.unwrap([m["heading_ref"] for _, m in reference]),
        [t for t, _ in sent], np.unwrap([m["heading"] for _, m in sent]),
        (min(moving), max(moving)),
    )  # fmt: skip
    print(f"separation: merged {separation}, report {expected['reference_separation_s']}")
    assert separation is not None and expected["reference_separation_s"] is not None
    assert abs(separation - expected["reference_separation_s"]) < 0.001


def _same_report_from_the_merged_file(run: Path, expected: dict[str, Any], out: Path) -> None:
    """``fedlab report RUN_DIR`` once merged reads the merged file and writes the
    summary.json the per-agent files gave: every field equal, floats exactly."""
    reported, _ = fedlab("report", str(run), "--out", str(out))
    assert reported.returncode == 0, reported.stdout + reported.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert expected["source"]["kind"] == "recordings"
    assert summary["source"] == {"kind": "merged", "files": ["merged.mcap"]}
    assert summary["followers"] and summary["sync"]  # figures, not only empty lists
    assert summary.keys() == expected.keys()
    for key in expected.keys() - {"source"}:
        assert summary[key] == expected[key], key

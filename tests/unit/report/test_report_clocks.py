"""The report on a run's identity and clocks: a demo run (recorded without a runs
folder) named from its run.json, the skew each agent was given shown to fixed precision
or said to be unknown, and the paper's clock offset set beside the run's as a scale,
not a target."""

from __future__ import annotations

import json
from typing import Any

from federation.core import paper
from federation.report.load import Run
from federation.report.markdown import CLOCKS_NOTE, markdown
from federation.report.summary import _clock_settings, comparison_rows, run_description

VERSIONS = {
    "fedlab_version": "0.1.0",
    "zenoh_version": "1.10.2",
    "python_version": "3.11.7",
    "git_commit": "abc",
}
RUN_JSON: dict[str, Any] = {
    "run_id": "attitude-tracking-demo-20260101T120000Z",
    "experiment": "attitude-tracking-demo",
    "utc_start": "2026-01-01T12:00:00+00:00",
    "versions": VERSIONS,
    "duration_s": 75.0,
    "agents": {
        "kiruna/knatte": {"clock_offset": 0.0, "clock_drift_ppm": 0.0},
        "rome/pinocchio-raw": {"clock_offset": 26.42 + 3.1, "clock_drift_ppm": 0.0},
    },
}


def test_a_demo_run_is_described_by_its_run_json() -> None:
    described = run_description(Run({}, RUN_JSON, [], "runs/demo"))
    assert described["run_id"] == RUN_JSON["run_id"]
    assert described["experiment"] == "attitude-tracking-demo"
    assert described["utc_start"] == "2026-01-01T12:00:00+00:00"
    assert described["versions"] == VERSIONS
    assert described["run_duration_s"] == 75.0


def test_without_run_json_nothing_is_made_up() -> None:
    described = run_description(Run({}, None, [], "runs/x"))
    assert described["run_id"] is None and described["utc_start"] is None
    assert set(described["versions"].values()) == {None}


def test_the_clock_skew_comes_from_the_settings_a_recording_holds() -> None:
    config = json.dumps({"clock_offset": 1.5, "clock_drift_ppm": 20, "seed": 0})
    assert _clock_settings(config) == {"clock_offset": 1.5, "clock_drift_ppm": 20.0}
    assert _clock_settings(None) == {"clock_offset": None, "clock_drift_ppm": None}
    assert _clock_settings("not json") == {"clock_offset": None, "clock_drift_ppm": None}


def _summary(settings: dict[str, Any]) -> dict[str, Any]:
    agent: dict[str, Any] = {"role": "follower", "platform": "pinocchio", "follow": "kiruna/knatte"}
    agent |= {"latency_compensation": False, "recording": "r.mcap"}
    return {
        "run_dir": "runs/demo",
        "run": {"run_id": "r1", "versions": {}, "clock_settings": settings},
        "followers": [],
        "agents": {"rome/pinocchio-raw": agent, "lab3/x": {**agent, "recording": "x.mcap"}},
        "sync": [{"client": "rome/pinocchio-raw", "peer": "kiruna/knatte"}],
        "notes": [],
    }


def test_the_agents_table_prints_each_skew_to_fixed_precision_or_says_why_unknown() -> None:
    settings = {"lab3/x": {"clock_offset": -7.3, "clock_drift_ppm": None}}
    text = markdown(_summary(settings), RUN_JSON)
    rows = {line.split(" | ")[0]: line for line in text.splitlines() if line.startswith("| ")}
    assert "| 29.520 | 0 |" in rows["| rome/pinocchio-raw"]  # not 29.520000000000003
    assert "| -7.300 | unknown |" in rows["| lab3/x"]
    assert "?" not in rows["| lab3/x"]
    assert CLOCKS_NOTE in text
    assert "arbitrary origin" in CLOCKS_NOTE and "tens of seconds" in CLOCKS_NOTE
    assert "Unknown: neither a run.json nor the agent's recorded settings say" in text


def test_the_papers_offset_is_a_scale_not_a_target() -> None:
    sync = {"client": "rome/pinocchio", "peer": "kiruna/knatte", "offset_median_s": 21.39}
    summary = {"sync": [sync], "followers": [], "agents": {}}
    row = comparison_rows(summary)[0]
    assert row == (
        "offset median (s; any value: arbitrary clock origins)",
        "rome/pinocchio → kiruna/knatte",
        "21.3900",
        f"{paper.CLOCK_OFFSET:.3f} (its labs' clocks)",
    )
    text = markdown(_summary({}), RUN_JSON)
    assert f"Its clock offset, {paper.CLOCK_OFFSET:.3f} s, is the gap between its two labs'" in text

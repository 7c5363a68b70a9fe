"""Reading a run from its merged file (federation/report/frommerged.py) on small
synthetic recordings: the Run, and the report made from it, equal those from the
per-agent recordings (every message, every summary.json field); which source a run
folder's report reads; and clear errors on files that are not a merged run."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from test_merge import KIRUNA, ROME, _record, _rejoined_run

from federation.report import write_report
from federation.report.frommerged import find_merged, load_merged, open_run
from federation.report.load import load_run
from federation.report.merge import write_merged
from schemas.config import ConfigError


@pytest.fixture
def run(tmp_path: Path) -> Path:
    folder = tmp_path / "run"
    folder.mkdir()
    _record(folder / "kiruna-knatte.mcap", KIRUNA, 600)
    _record(folder / "rome-pinocchio.mcap", ROME, 600, wall_off=3.0)
    (folder / "run.json").write_text(json.dumps({
        "leader": KIRUNA, "duration_s": 7,
        "agents": {KIRUNA: {"role": "leader"}, ROME: {"role": "follower", "follow": KIRUNA,
                   "latency_compensation": True}},
        "link": {"delay_ms": 40, "jitter_ms": 0},
    }))  # fmt: skip
    return folder


def _same_runs(a: Any, b: Any) -> None:
    assert list(a.agents) == list(b.agents)
    for name, rec in a.agents.items():
        other = b.agents[name]
        assert rec.messages == other.messages, name  # every message, in order, floats exact
        assert rec.segments == other.segments, name
        assert (rec.file, rec.role, rec.follow, rec.platform, rec.latency_compensation) == (
            other.file, other.role, other.follow, other.platform, other.latency_compensation,
        )  # fmt: skip
        assert rec.metadata == other.metadata, name
    assert a.meta == b.meta and a.notes == b.notes and a.directory == b.directory


def test_the_merged_file_gives_the_run_the_recordings_give(run: Path) -> None:
    recorded = load_run(run)
    write_merged(run)
    merged = load_merged(run / "merged.mcap")
    assert merged.from_merged and not recorded.from_merged
    assert merged.sources == ["merged.mcap"]
    assert recorded.sources == ["kiruna-knatte.mcap", "rome-pinocchio.mcap"]  # merged.mcap not
    assert sum(len(v) for v in merged.agents[ROME].messages.values()) == 600 * 3 + 12 + 1
    _same_runs(recorded, merged)


def test_a_rejoined_agents_segments_come_back_as_segments(tmp_path: Path) -> None:
    run = tmp_path / "run"
    _rejoined_run(run)
    recorded = load_run(run)
    write_merged(run)
    merged = load_merged(run / "merged.mcap")
    assert len(merged.agents[ROME].segments) == 2
    assert merged.agents[ROME].file == "rome-pinocchio.mcap, rome-pinocchio.seg2.mcap"
    _same_runs(recorded, merged)


def _without_source(summary: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in summary.items() if k != "source"}


def test_the_report_from_the_merged_file_equals_the_one_from_the_recordings(
    run: Path, tmp_path: Path
) -> None:
    from_recordings = write_report(run, tmp_path / "a", source="recordings")
    write_merged(run)
    from_merged = write_report(run, tmp_path / "b")  # auto: the merged file
    assert from_recordings["source"] == {
        "kind": "recordings", "files": ["kiruna-knatte.mcap", "rome-pinocchio.mcap"],
    }  # fmt: skip
    assert from_merged["source"] == {"kind": "merged", "files": ["merged.mcap"]}
    a = json.loads((tmp_path / "a" / "summary.json").read_text())
    b = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert a["followers"] and a["agents"][ROME]["heading_rms_error_deg"] is not None
    for key in a.keys() - {"source"}:
        assert a[key] == b[key], key
    assert a.keys() == b.keys()
    assert _without_source(from_recordings) == _without_source(from_merged)
    assert "Source: the merged run `merged.mcap`" in (tmp_path / "b" / "report.md").read_text()
    assert "Source: the per-agent recordings" in (tmp_path / "a" / "report.md").read_text()


def test_a_run_folder_reads_its_merged_file_only_while_it_matches_the_recordings(
    run: Path,
) -> None:
    assert not open_run(run).from_merged  # no merged file yet
    write_merged(run)
    assert open_run(run).from_merged
    assert not open_run(run, "recordings").from_merged
    # A recording added after the merge (collect resumed): the recordings, and why.
    _record(run / "lulea-lisa.mcap", "lulea/lisa", 100)
    stale = open_run(run)
    assert not stale.from_merged and "lulea/lisa" in stale.agents
    assert (
        "merged.mcap was not merged from these recordings (lulea-lisa.mcap is not in it)"
        in (stale.notes[0])
    )
    assert open_run(run, "merged").from_merged  # asked for: read all the same
    assert open_run(run / "merged.mcap").from_merged


def test_files_that_are_not_a_merged_run_are_refused_with_why(run: Path, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no merged file; write one with fedlab merge"):
        open_run(run, "merged")
    with pytest.raises(ConfigError, match=r"not a merged run \(no fedlab.merge"):
        load_merged(run / "rome-pinocchio.mcap")
    cut = tmp_path / "cut.mcap"
    write_merged(run, cut)
    cut.write_bytes(cut.read_bytes()[:-100])
    with pytest.raises(ConfigError, match="not a finished MCAP file"):
        load_merged(cut)
    with pytest.raises(ConfigError, match="no such run folder or merged file"):
        open_run(tmp_path / "nowhere")
    with pytest.raises(ConfigError, match="a file; the recordings are read from their run folder"):
        open_run(run / "rome-pinocchio.mcap", "recordings")
    write_merged(run, run / "one.mcap")
    write_merged(run, run / "two.mcap")
    with pytest.raises(ConfigError, match=r"several merged files \(one.mcap, two.mcap\)"):
        find_merged(run)
    write_merged(run)
    assert find_merged(run) == run / "merged.mcap"  # the default name wins


def test_an_agent_the_merge_left_out_is_named_in_a_note(run: Path) -> None:
    # Lulea's recording holds only /pose/sent: no estimate of the reference clock.
    _record(run / "lulea-lisa.mcap", "lulea/lisa", 100)
    from mcap.reader import make_reader
    from mcap.writer import Writer

    source, target = run / "lulea-lisa.mcap", run / "lulea-lisa.tmp"
    with source.open("rb") as f, target.open("wb") as out:
        writer = Writer(out)
        writer.start(profile="", library="test")
        ids: dict[str, int] = {}
        for _s, channel, message in make_reader(f).iter_messages():
            if channel.topic != "/pose/sent":
                continue
            if channel.topic not in ids:
                ids[channel.topic] = writer.register_channel(channel.topic, "json", 0)
            writer.add_message(ids[channel.topic], message.log_time, message.data,
                               message.publish_time)  # fmt: skip
        writer.finish()
    target.replace(source)
    write_merged(run)
    merged = open_run(run)
    assert merged.from_merged and "lulea/lisa" not in merged.agents
    assert any(n.startswith("lulea-lisa.mcap: not in the merged file") for n in merged.notes)

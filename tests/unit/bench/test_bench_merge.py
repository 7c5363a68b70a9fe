"""``fedlab bench merge``'s plumbing on a run of 2 MiB: the synthetic run is the same
bytes from the same seed, the merge and the baseline run as child processes, the
result holds what the README's table reads, and a budget below the measured peak
fails the command with a message naming both."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from federation import cli
from federation.bench import merge as bench
from federation.bench import table

ROOT = Path(__file__).resolve().parents[3]


def test_the_synthetic_run_is_the_same_bytes_from_the_same_seed(tmp_path: Path) -> None:
    first = bench.write_run(tmp_path / "a", 200_000, agents=3, seed=7)
    again = bench.write_run(tmp_path / "b", 200_000, agents=3, seed=7)
    bench.write_run(tmp_path / "c", 200_000, agents=3, seed=8)
    assert first["files"] == again["files"] and len(first["files"]) == 3
    assert first["bytes"] >= 200_000 and first["messages"] > 1000
    for name in first["files"]:
        same = (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
        assert same, name
    follower = "rome-pinocchio.mcap"
    assert (tmp_path / "a" / follower).read_bytes() != (tmp_path / "c" / follower).read_bytes()


def test_a_run_below_two_agents_is_refused() -> None:
    with pytest.raises(ValueError, match="2 agents or more"):
        bench.agent_names(1)


def test_the_result_feeds_the_table_and_a_budget_below_the_peak_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "merge-2gib.json"
    argv = ["bench", "merge", "--size", "2", "--repeats", "1", "--budget", "1"]
    code = cli.main([*argv, "--dir", str(tmp_path / "work"), "--json-out", str(out)])
    err = capsys.readouterr().err
    assert code == 1, err
    result = json.loads(out.read_text(encoding="utf-8"))
    peak = result["merge"]["peak_rss_mib"]["max"]
    assert "exceeds the budget of 1 MiB" in err and f"{peak:.1f} MiB" in err
    assert result["within_budget"] is False and result["budget_mib"] == 1
    assert not any((tmp_path / "work").iterdir()), "the synthetic run was left behind"
    # Measured, not made up: each child's peak and rate, the ratio of the two.
    for what in ("merge", "baseline"):
        for key in ("peak_rss_mib", "mib_per_s", "wall_s"):
            assert result[what][key]["min"] > 0, (what, key)
    merge_row, base_row = result["rows"][1], result["rows"][0]
    assert (merge_row["what"], base_row["what"]) == ("merge", "baseline")
    ratio = merge_row["mib_per_s"] / base_row["mib_per_s"]
    assert result["ratios"]["mib_per_s"]["median"] == pytest.approx(ratio, rel=1e-2)
    assert result["run"]["mib"] >= 2 and len(result["run"]["agents"]) == 4
    # Within a budget above the peak the same figures pass.
    bench.check(result | {"budget_mib": peak + 1})
    # The table reads it beside the committed result files.
    folder = tmp_path / "benchmarks"
    shutil.copytree(ROOT / "benchmarks", folder, ignore=shutil.ignore_patterns("merge-2gib.json"))
    shutil.copy(out, folder / "merge-2gib.json")
    (row,) = [r for r in table.rows(folder) if r[4] == "merge-2gib.json"]
    assert (
        row[0].startswith("merge,") and f"{result['merge']['peak_rss_mib']['median']:.1f}" in row[2]
    )

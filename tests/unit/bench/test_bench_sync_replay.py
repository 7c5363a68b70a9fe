"""The clock filter on exchanges recorded in the namespace testbed (issue 16's
scenarios: the paper's 40 ms link, Rome behind NAT, loss 1 to 20 %, a 10 s cut,
MTU 576), saved with ``fedlab bench sync --replay ... --save``; and the replay
command's own file handling."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest

from federation.bench.sync import load_runs, load_saved, replay, replay_runs, save_recordings

DATA = Path(__file__).parents[3] / "benchmarks" / "data" / "testbed-sync-exchanges.json.gz"


@pytest.fixture(scope="module")
def testbed() -> dict:
    return load_saved(DATA)


def _p95_ms(testbed: dict, scenario: str) -> dict[str, float]:
    return {
        name: replay(rec, "clockfilter")["p95"] * 1e3
        for name, rec in testbed.items()
        if name.split("/")[1].startswith(scenario + "-")
    }


def test_the_saved_file_holds_both_transports_and_every_scenario(testbed: dict) -> None:
    scenarios = {name.split("/")[1].rsplit("-", 1)[0] for name in testbed}
    assert {f"{s}-tcp-tuned" for s in ("clean", "loss1", "loss5", "loss20", "cut10")} <= scenarios
    assert {f"{s}-multilink" for s in ("clean", "loss1", "loss5", "loss20", "cut10")} <= scenarios
    assert all(len(rec.exchanges) > 400 for rec in testbed.values())


@pytest.mark.parametrize("scenario", ["loss1", "loss5"])
def test_sync_error_p95_under_0_3_ms_at_1_and_5_percent_loss(testbed: dict, scenario: str) -> None:
    p95 = _p95_ms(testbed, scenario)
    assert len(p95) == 4 and max(p95.values()) < 0.3, p95


def test_sync_error_p95_at_20_percent_loss(testbed: dict) -> None:
    # TCP: 0.36 and 0.19 ms (the estimator before: 1.00 and 1.35). Multilink: 0.92 and
    # 1.08 ms; the second run's first 15 s held no exchange within 5 ms of the
    # fastest round trip, and no estimator can beat the data it has.
    p95 = _p95_ms(testbed, "loss20")
    tcp = [v for k, v in p95.items() if "tcp" in k]
    assert len(tcp) == 2 and max(tcp) < 1.0, p95
    assert max(p95.values()) < 1.2, p95


def test_save_and_load_round_trip(testbed: dict, tmp_path: Path) -> None:
    some = dict(list(testbed.items())[:2])
    out = tmp_path / "two.json.gz"
    save_recordings(out, some)
    again = load_runs([out])
    assert list(again) == list(some)
    for name in some:
        assert again[name].exchanges == some[name].exchanges
        t = some[name].exchanges[-1].t3
        assert again[name].truth(t) == some[name].truth(t)
    assert replay_runs(again, ["clockfilter"]) == replay_runs(some, ["clockfilter"])


def test_bad_replay_inputs_fail_naming_the_path(tmp_path: Path) -> None:
    empty = tmp_path / "run"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"run: a run folder needs follower\.mcap"):
        load_runs([empty])
    junk = tmp_path / "junk.json.gz"
    junk.write_bytes(b"not gzip")
    with pytest.raises(ValueError, match=r"junk\.json\.gz: not a file of saved sync recordings"):
        load_runs([junk])
    other = tmp_path / "other.json.gz"
    with gzip.open(other, "wt") as f:
        json.dump({"format": "something-else"}, f)
    with pytest.raises(ValueError, match="something-else"):
        load_runs([other])

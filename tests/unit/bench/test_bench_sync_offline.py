"""``fedlab bench sync`` offline: simulated exchanges scored by each estimator, restarts,
and truth recovered from recordings; no routers (the live run is in
tests/integration/test_bench_sync.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from federation.bench.sync import (
    CLOCK_OFFSET,
    SCENARIOS,
    load_recording,
    replay,
    replay_trials,
    simulate,
)
from federation.runtime.recorder import Recorder


def test_offline_drift_scenario_clockfilter_beats_the_paper() -> None:
    rec = simulate(SCENARIOS["drift"], duration=120, seed=3)
    ours = replay(rec, "clockfilter")
    paper = replay(rec, "mean")
    assert ours["p95"] < 0.5e-3
    assert paper["p95"] > 2e-3  # 50 ppm for 110 s after the window: ~5 ms
    assert ours["n"] == paper["n"]
    assert 1095 <= ours["n"] <= 1100  # 1200 exchanges less the 10 s sync phase


def test_offline_asymmetry_is_half_the_difference_for_every_estimator() -> None:
    rec = simulate(SCENARIOS["asymmetry"], duration=60, seed=3)
    for name in ("clockfilter", "mean", "median"):
        assert replay(rec, name)["p50"] == pytest.approx(0.005, abs=1e-3)


def test_offline_is_reproducible_and_seeded() -> None:
    a = replay(simulate(SCENARIOS["heavy-tail"], 30, seed=1), "mean")
    b = replay(simulate(SCENARIOS["heavy-tail"], 30, seed=1), "mean")
    c = replay(simulate(SCENARIOS["heavy-tail"], 30, seed=2), "mean")
    assert a == b and a != c


def test_restarts_score_fresh_estimators_over_the_recording() -> None:
    rec = simulate(SCENARIOS["paper-like"], duration=120, seed=3)
    span = rec.exchanges[-1].t3 - rec.exchanges[0].t3
    one = replay_trials(rec, "mean", length=60.0, every=10.0)
    assert one["trials"] == int((span - 60.0) // 10.0) + 1 == 6
    # Each start scores its own 50 s after its sync phase: 500 exchanges.
    assert one["n"] == pytest.approx(6 * 500, abs=6)
    # The paper's mean holds one draw per start: six different values, not one.
    single = replay(rec, "mean")
    assert single["p50"] == pytest.approx(single["max"]) and one["p50"] < 0.5 * one["max"]
    # A recording without noise scores zero for every start.
    clean = simulate(SCENARIOS["paper-like"], duration=80, seed=3)
    exact = type(clean)(
        [type(e)(e.t1, e.t1 + CLOCK_OFFSET + 0.02, e.t1 + 0.04) for e in clean.exchanges],
        lambda t: CLOCK_OFFSET,
    )
    assert replay_trials(exact, "clockfilter", length=30.0)["max"] == pytest.approx(0, abs=1e-9)
    with pytest.raises(ValueError, match="longer recording"):
        replay_trials(rec, "mean", length=200.0)


def test_offline_restarts_clockfilter_no_worse_than_the_paper_without_drift() -> None:
    for name in ("paper-like", "heavy-tail"):
        rec = simulate(SCENARIOS[name], duration=120, seed=1)
        ours, paper = replay_trials(rec, "clockfilter"), replay_trials(rec, "mean")
        assert ours["p95"] <= paper["p95"], (name, ours, paper)
    # Bursts: the offset listens to its 4 fastest exchanges (what a 20 %-loss link
    # needs), which on this path costs some tail: p95 0.27 against the paper's
    # 0.235 ms for seed 1, while the median is three times better.
    rec = simulate(SCENARIOS["bursts"], duration=120, seed=1)
    ours, paper = replay_trials(rec, "clockfilter"), replay_trials(rec, "mean")
    assert ours["p50"] < 0.5 * paper["p50"] and ours["p95"] <= 1.2 * paper["p95"], (ours, paper)


def test_replay_needs_time_after_the_sync_phase() -> None:
    with pytest.raises(ValueError, match="sync phase"):
        replay(simulate(SCENARIOS["paper-like"], 5), "mean")


def test_cli_offline_json() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "federation", "bench", "sync", "--offline", "--duration", "30",
         "--scenario", "drift", "--json"],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert {r["estimator"] for r in rows} == {"clockfilter", "mean", "median"}
    for r in rows:
        assert r["scenario"] == "drift"
        assert 0 <= r["p50"] <= r["p95"] <= r["max"]


def test_load_recording_recovers_drifting_clocks(tmp_path: Path) -> None:
    """Truth from recorded status: clocks as exact linear functions of host time."""
    server, client = tmp_path / "s.mcap", tmp_path / "c.mcap"
    rate_s, rate_c = 1 + 50e-6, 1 - 20e-6
    for path, a, rate in ((server, 3.0, rate_s), (client, -7.0, rate_c)):
        rec = Recorder(path, "x/y")
        for h in (100.0, 150.0, 200.0):
            rec.record("/status", {"t_exec": a + (h - 100) * rate, "host_monotonic": h})
        if path == client:
            exchange = {"peer": "kiruna/knatte", "t1": 0.0, "t2": 10.0, "t3": 0.1, "t2s": None}
            rec.record("/sync/exchange", exchange)
            rec.record("/sync/exchange", exchange | {"peer": "rome/other"})
        rec.close()
    rec_ = load_recording(client, server)
    t_client = -7.0 + 50 * rate_c  # host 150
    assert rec_.truth(t_client) == pytest.approx((3.0 + 50 * rate_s) - t_client, abs=1e-9)
    assert len(rec_.exchanges) == 1  # only the exchanges with the named peer

"""``fedlab bench sync``: offline scoring, and a short live run through the link emulator."""

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
    run_live,
    simulate,
)
from federation.estimators import make_estimator


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


@pytest.mark.integration
def test_live_run_matches_offline_replay_of_its_own_recording(tmp_path: Path) -> None:
    """Real routers, link emulator (40 ms) and agents; the follower's own live estimate
    equals the replay of the exchanges it recorded, and the truth is recovered."""
    rec = run_live(SCENARIOS["paper-like"], duration=16, out=tmp_path, seed=5)
    assert len(rec.exchanges) > 100
    delays = sorted(ex.delay for ex in rec.exchanges)
    assert 0.040 <= delays[len(delays) // 2] < 0.052  # 40 ms + half-normal 5 ms jitter
    score = replay(rec, "clockfilter")
    assert score["p95"] < 2e-3
    # The follower's status lines: its live estimate at each status instant is what
    # the replay of the same exchanges gives at that instant.
    from federation.recorder import read_messages

    recorded = read_messages(tmp_path / "paper-like-follower.mcap", ["/status"])["/status"]
    status = [s for s in recorded if s["peers"].get("kiruna/knatte", {}).get("samples", 0) > 0]
    assert status
    matched = 0
    for line in status:
        view = line["peers"]["kiruna/knatte"]
        est = make_estimator("clockfilter")
        for ex in rec.exchanges[: view["samples"]]:
            est.add(ex)
        if est.offset_at(line["t_exec"]) == pytest.approx(view["offset"], abs=1e-9):
            matched += 1
    # A reply landing between the status read of t_exec and of the estimator may
    # make a line one exchange ahead; nearly all match exactly.
    assert matched >= 0.9 * len(status), (matched, len(status))
    truth = rec.truth(rec.exchanges[-1].t3)
    assert truth == pytest.approx(-CLOCK_OFFSET, abs=3.0)


def test_load_recording_recovers_drifting_clocks(tmp_path: Path) -> None:
    """Truth from recorded status: clocks as exact linear functions of host time."""
    from federation.recorder import Recorder

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

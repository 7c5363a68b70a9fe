"""``fedlab bench sync`` live: a short run through the link emulator, checked against the
offline replay of its own recording (offline scoring: tests/unit/bench/)."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.bench.sync import CLOCK_OFFSET, SCENARIOS, replay, run_live
from federation.core.estimators import make_estimator
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration


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

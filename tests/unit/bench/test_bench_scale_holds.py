"""The scale bench's safe-hold and loop-stall figures, from status reports and the
leader's publication times."""

from __future__ import annotations

import json
import math
from pathlib import Path

from federation.bench.scale import (
    SETTLE,
    _counted_between,
    _hold_scores,
    _latency_and_loss,
    _listening,
    _pose_gaps,
    _score_bare,
    summary,
)


def status(host: float, holds: int) -> dict[str, object]:
    return {"host_monotonic": host, "counters": {"stale_holds": holds} if holds else {}}


def test_holds_are_counted_inside_the_window_only() -> None:
    # One hold before the window (start-up), two inside, one after (the leader stopped).
    reports = [status(1.0, 1), status(2.0, 1), status(3.0, 2), status(4.0, 3), status(5.0, 4)]
    assert _counted_between(reports, "stale_holds", start=2.5, end=4.5) == 2
    # A window that starts before the first report counts from zero.
    assert _counted_between(reports, "stale_holds", start=0.5, end=4.5) == 3
    assert _counted_between([], "stale_holds", start=0.0, end=9.0) == 0
    assert _counted_between(reports, "pose_stale_dropped", start=0.5, end=4.5) == 0


def test_loss_is_counted_by_follower_from_when_its_routes_settled() -> None:
    sent = [i * 0.05 for i in range(200)]  # 10 s at 20 Hz
    whole = [(t, t + 0.001) for t in sent]
    # The second follower misses five poses after settling and one before (not counted).
    gaps = {10, 100, 101, 102, 103, 104}
    second = [(t, h) for i, (t, h) in enumerate(whole) if i not in gaps]
    scores = _latency_and_loss(sent, [whole, second], lambda t: t)
    window = sum(1 for t in sent if t >= SETTLE)
    assert scores["lost"] == [0, 5]
    assert scores["expected"] == 2 * window
    assert scores["loss"] == 5 / (2 * window)
    # A follower that got nothing lost everything the leader sent.
    assert _latency_and_loss(sent, [whole, []], lambda t: t)["lost"] == [0, 200]


def test_hold_scores_sum_holds_and_count_followers_held() -> None:
    assert _hold_scores([0, 2, 0, 1]) == {"stale_holds": 3, "followers_held": 2}
    assert _hold_scores([]) == {"stale_holds": 0, "followers_held": 0}


def test_pose_gaps_find_a_stalled_loop() -> None:
    published = [i * 0.05 for i in range(40)]
    steady = _pose_gaps(published)
    assert steady["leader_gaps_over_2x"] == 0
    assert math.isclose(steady["leader_gap_max_ms"], 50.0, rel_tol=1e-6)
    stalled = published[:20] + [t + 0.15 for t in published[20:]]  # one 200 ms gap
    gaps = _pose_gaps(stalled)
    assert gaps["leader_gaps_over_2x"] == 1
    assert math.isclose(gaps["leader_gap_max_ms"], 200.0, rel_tol=1e-6)
    assert math.isnan(_pose_gaps([0.0, 0.05])["leader_gap_max_ms"])


def test_pose_gaps_in_the_window_leave_out_start_up_and_wind_down() -> None:
    # A cold first tick (120 ms) and a last one late (90 ms) around a steady 50 ms loop.
    published = [0.0] + [0.12 + i * 0.05 for i in range(40)]
    published.append(published[-1] + 0.09)
    steady = _pose_gaps(published, window=(0.12, published[-2]))
    assert math.isclose(steady["leader_gap_max_ms"], 50.0, rel_tol=1e-6)
    assert steady["leader_gaps_over_2x"] == 0
    assert math.isclose(steady["leader_gap_max_all_ms"], 120.0, rel_tol=1e-6)
    # A stall inside the window is still found.
    stalled = published[:20] + [t + 0.2 for t in published[20:]]
    gaps = _pose_gaps(stalled, window=(0.12, stalled[-2]))
    assert math.isclose(gaps["leader_gap_max_ms"], 250.0, rel_tol=1e-6)
    assert gaps["leader_gaps_over_2x"] == 1


def test_a_window_too_short_keeps_the_whole_runs_gap() -> None:
    published = [0.0] + [0.12 + i * 0.05 for i in range(40)]
    gaps = _pose_gaps(published, window=(5.0, 5.01))  # no pose in it
    assert math.isnan(gaps["leader_gap_max_ms"]) and gaps["leader_gaps_over_2x"] == 0
    assert math.isclose(gaps["leader_gap_max_all_ms"], 120.0, rel_tol=1e-6)


def test_the_floor_is_scored_in_the_window_its_followers_listened(tmp_path: Path) -> None:
    # The bare floor's leader stamps host time: a 300 ms start-up gap, then 50 ms ticks
    # from 0.3 s to 9.8 s; two followers hear from 0.3 s (one stops at 8.0 s).
    sent = [0.0] + [0.3 + i * 0.05 for i in range(191)]
    heard = [[t, t + 0.001] for t in sent[1:]]
    data = {"sent": sent, "received": {"a1": heard, "a2": [p for p in heard if p[0] <= 8.0]},
            "replies": {"a1": 10}, "seconds": 10.0}  # fmt: skip
    (tmp_path / "bare-lab1.json").write_text(json.dumps(data))
    scores = _score_bare(tmp_path, "lab0/a0")
    assert math.isclose(scores["leader_gap_max_ms"], 50.0, rel_tol=1e-6)
    assert math.isclose(scores["leader_gap_max_all_ms"], 300.0, rel_tol=1e-6)


def test_listening_is_the_window_every_follower_heard() -> None:
    # (stamp, host arrival): one follower from 1.0 to 9.0 s, one from 2.0 to 8.0 s.
    early = [(t, t + 0.001) for t in (1.0, 5.0, 9.0)]
    late = [(t, t + 0.001) for t in (2.0, 5.0, 8.0)]
    window = _listening([early, late, []])  # one that heard nothing is left out
    assert window is not None
    start, end = window
    assert math.isclose(start, 2.001 + SETTLE) and math.isclose(end, 8.001)
    assert _listening([[], []]) is None and _listening([]) is None


def row(mode: str, run: int, **extra: float) -> dict[str, object]:
    base = {"n": 4, "mode": mode, "run": run, "cpu_per_agent": 0.01, "cpu_cores": 0.04,
            "p50_ms": 1.0, "p99_ms": 2.0, "loss": 0.0, "sync_per_s": 30.0,
            "leader_gap_max_ms": 60.0, "leader_gap_max_all_ms": 80.0}  # fmt: skip
    return base | extra


def test_summary_gives_holds_for_fedlab_and_gaps_for_both() -> None:
    rows = [row("default", k, stale_holds=k) for k in range(3)] + [row("bare", k) for k in range(3)]
    table = summary(rows)["4"]  # type: ignore[arg-type]
    assert table["default"]["stale_holds"] == {"median": 1.0, "min": 0, "max": 2}
    assert "stale_holds" not in table["bare"]
    assert table["bare"]["leader_gap_max_ms"]["median"] == 60.0
    assert table["default"]["leader_gap_max_all_ms"] == {"median": 80.0, "min": 80.0, "max": 80.0}

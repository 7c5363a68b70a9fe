"""``fedlab bench network``'s scoring (federation/bench/network.py ``score``) on
made-up recordings: the scored window starts ``sync_phase`` after the first sync
exchange, and the leader's own longest pause between poses is reported."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from federation.bench import network
from federation.runtime import recorder

PERIOD = 0.05  # s, 20 Hz
DELAY = 0.04  # s, one way


def _recordings(
    end: float, leader_pause: tuple[float, float] | None, holds: list[float]
) -> dict[str, dict[str, list[dict[str, Any]]]]:
    """A leader sending poses from 0 to ``end`` (host s; silent over ``leader_pause``),
    a follower receiving each ``DELAY`` later, exchanging every 0.1 s from 0.5 s and
    entering a stale hold at each of ``holds``. Both clocks are the host's."""
    sends = [round(k * PERIOD, 6) for k in range(int(end / PERIOD) + 1)]
    if leader_pause is not None:
        a, b = leader_pause
        sends = [t for t in sends if not a < t < b]
    status = [{"host_monotonic": t, "t_exec": t, "counters": {}} for t in (0.0, end)]
    follower = {
        "/status": status,
        "/pose/received": [{"host_monotonic": t + DELAY, "t": t} for t in sends],
        "/sync/exchange": [
            {
                "host_monotonic": 0.5 + 0.1 * k,
                "t3": 0.5 + 0.1 * k,
                "estimate": 0.0,
                "peer": network.LEADER,
                "delay": DELAY,
            }
            for k in range(int((end - 0.5) / 0.1))
        ],
        "/control": [{"host_monotonic": h, "event": "stale_hold"} for h in holds],
        "/reference": [],
    }
    leader = {
        "/status": status,
        "/pose/sent": [{"host_monotonic": t, "heading": 0.0} for t in sends],
    }
    return {"follower": follower, "leader": leader}


def _score(
    monkeypatch: pytest.MonkeyPatch, recordings: dict[str, Any], **kw: Any
) -> dict[str, Any]:
    def read(path: Path, topics: list[str]) -> dict[str, list[dict[str, Any]]]:
        rec = recordings[path.stem]
        return {topic: rec.get(topic, []) for topic in topics}

    monkeypatch.setattr(recorder, "read_messages", read)
    return network.score(Path("follower.mcap"), Path("leader.mcap"), {}, {}, **kw)


def test_a_hold_in_the_sync_phase_counts_only_once_the_phase_is_shorter(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    recordings = _recordings(20.0, None, holds=[7.0])  # first exchange at 0.5 s
    assert _score(monkeypatch, recordings)["holds"] == 0  # the paper's 10 s phase
    assert _score(monkeypatch, recordings, sync_phase=5.0)["holds"] == 1


def test_the_leaders_longest_pause_between_poses_is_reported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    paused = _score(monkeypatch, _recordings(20.0, (14.0, 14.3), holds=[14.25]), sync_phase=5.0)
    assert paused["holds"] == 1
    assert paused["sender_gap_max_ms"] == pytest.approx(300.0, abs=1.0)  # 14.0 to 14.3
    steady = _score(monkeypatch, _recordings(20.0, None, holds=[]), sync_phase=5.0)
    assert steady["sender_gap_max_ms"] == pytest.approx(PERIOD * 1e3, abs=1.0)


def test_a_pause_before_the_scored_start_is_not_the_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    result = _score(monkeypatch, _recordings(20.0, (2.0, 3.0), holds=[]), sync_phase=5.0)
    assert result["sender_gap_max_ms"] == pytest.approx(PERIOD * 1e3, abs=1.0)


def test_a_poses_age_is_judged_beyond_the_delay_the_follower_estimated_then(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The stale rule's own terms: a pose's latency less the median of the follower's
    last DELAY_WINDOW exchanges with the leader before it arrived."""
    recordings = _recordings(20.0, None, [])
    follower = recordings["follower"]
    exchanges = follower["/sync/exchange"]
    for x in exchanges[-60:]:  # the host's queueing raises the last 60 exchanges' delay
        x["delay"] = 0.06
    exchanges.append({"host_monotonic": 19.0, "peer": "lab/other", "delay": 5.0})  # not the leader
    exchanges.sort(key=lambda x: x["host_monotonic"])
    late = {"host_monotonic": 19.5 + 0.3, "t": 19.5}  # 300 ms old
    follower["/pose/received"].append(late)
    result = _score(monkeypatch, recordings, sync_phase=1.0)
    assert result["pose_latency_ms"]["max"] == pytest.approx(300.0)
    # Judged against 60 ms (the last 50 exchanges' median), not the path's 40 ms.
    assert result["pose_age_beyond_delay_ms"]["max"] == pytest.approx(240.0)
    # Against the earlier exchanges' 40 ms where those are the last 50.
    for x in exchanges[-60:]:
        x["delay"] = DELAY
    assert _score(monkeypatch, recordings, sync_phase=1.0)["pose_age_beyond_delay_ms"][
        "max"
    ] == pytest.approx(260.0)

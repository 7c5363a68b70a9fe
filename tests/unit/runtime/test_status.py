"""Status building blocks (federation/runtime/status.py)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core.clockfilter import ClockFilter
from federation.core.sync import PaperEstimator, SyncClient, serve
from federation.core.wire import Pose, encode_reply
from federation.runtime.status import loop_stats, peer_status


def synced(estimator: PaperEstimator | ClockFilter, offset: float = 26.42) -> SyncClient:
    """A client with ten accepted exchanges, 40 ms each way, one unmatched reply."""
    client = SyncClient(estimator, timeout=1.0)
    for k in range(10):
        t1 = 0.1 * k
        t2 = t1 + 0.04 + offset
        client.receive(serve(client.request(t1), t2, Pose(), t2).payload, t1 + 0.08)
    client.receive(encode_reply(99.0, 1.0, Pose()), 5.1)  # answers no request
    return client


def test_peer_status_reports_the_client() -> None:
    view = peer_status(synced(PaperEstimator()), t=1.0, alive=True)
    assert view.offset == pytest.approx(26.42)
    assert view.delay == pytest.approx(0.04)
    assert view.last_offset == pytest.approx(26.42) and view.last_delay == pytest.approx(0.04)
    assert view.error_bound == pytest.approx(0.04)
    assert (view.samples, view.sent, view.rejected, view.alive) == (10, 10, 1, True)
    assert view.rejected_by_reason == {"unmatched": 1}
    assert view.drift_ppm is None and not view.locked and view.clock_steps == 0


def test_peer_status_reports_against_another_clock_and_the_drift() -> None:
    view = peer_status(synced(ClockFilter()), t=1.0, alive=False, base=26.0)
    assert view.offset == pytest.approx(0.42, abs=1e-6)
    assert view.last_offset == pytest.approx(0.42, abs=1e-9)
    assert view.drift_ppm == pytest.approx(0.0, abs=1.0) and not view.alive


def test_peer_status_of_a_client_never_answered() -> None:
    view = peer_status(SyncClient(PaperEstimator()), t=0.0, alive=True)
    assert (view.offset, view.delay, view.last_offset, view.samples) == (None, None, None, 0)


def test_loop_stats() -> None:
    assert loop_stats(100.0, []) == {"rate_hz": 100.0, "ticks": 0.0}
    stats = loop_stats(50.0, [0.001 * k for k in range(100, 0, -1)])
    assert stats["ticks"] == 100.0
    assert stats["late_p50_ms"] == pytest.approx(51.0)
    assert stats["late_p99_ms"] == pytest.approx(100.0)
    assert stats["late_max_ms"] == pytest.approx(100.0)


@given(st.lists(st.floats(-1.0, 10.0), max_size=2500))
def test_loop_stats_order_statistics_equal_a_full_sort(lateness: list[float]) -> None:
    """Partitioned, not sorted (issue 17): the same three order statistics."""
    late = sorted(lateness)
    n = len(late)
    stats = loop_stats(20.0, lateness)
    assert stats["ticks"] == float(n)
    if n:
        assert stats["late_p50_ms"] == late[n // 2] * 1e3
        assert stats["late_p99_ms"] == late[min(n - 1, int(0.99 * n))] * 1e3
        assert stats["late_max_ms"] == late[-1] * 1e3

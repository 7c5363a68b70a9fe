"""The link watch's incremental statistics against the straightforward computation
over its window (federation/core/linkwatch.py)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from federation.core.linkwatch import WINDOW, LinkWatch, loss_upper_bound, stale_threshold


def straightforward(gaps: list[tuple[float, float]], stale_after: float, ceiling: float) -> tuple:
    """Period, loss, sigma and threshold recomputed from every gap of the window."""
    sends = sorted(g[0] for g in gaps)
    period = sends[len(sends) // 2]
    slots = [max(1, round(s / period)) for s, _ in gaps]
    expected = sum(slots)
    loss = (expected - len(slots)) / expected
    jitter = [a - s for s, a in gaps]
    mean = sum(jitter) / len(jitter)
    sigma = math.sqrt(sum((j - mean) ** 2 for j in jitter) / len(jitter))
    bound = loss_upper_bound(expected - len(slots), expected)
    return period, loss, sigma, stale_threshold(period, bound, sigma, stale_after, ceiling)


# One pose stream: each step skips some poses (lost) and arrives with some jitter.
steps = st.lists(
    st.tuples(
        st.integers(min_value=1, max_value=8),  # periods since the last pose received
        st.floats(min_value=-0.02, max_value=0.2, allow_nan=False),  # extra arrival delay
    ),
    min_size=41,
    max_size=3 * WINDOW,
)


@settings(max_examples=60, deadline=None)
@given(steps, st.sampled_from([0.01, 0.05, 0.1]), st.floats(min_value=0.001, max_value=0.05))
def test_incremental_statistics_equal_the_straightforward_ones(
    stream: list[tuple[int, float]], period: float, base_delay: float
) -> None:
    watch = LinkWatch(0.1)
    sent = 1000.0
    measured = 0
    for skip, extra in stream:
        sent += skip * period
        watch.observe(sent - 990.0 + base_delay + extra, sent)
        if watch._fresh == 0 and len(watch._gaps) >= 40:  # it has just measured
            measured += 1
            expect = straightforward(list(watch._gaps), watch.stale_after, watch.ceiling)
            assert watch.period == expect[0]
            assert watch.loss == expect[1]  # integer slot counts: exactly the same
            assert watch.sigma == pytest.approx(expect[2], rel=1e-9, abs=1e-12)
            assert watch.threshold == pytest.approx(expect[3], rel=1e-9, abs=1e-12)
    assert sorted(g[0] for g in watch._gaps) == list(watch._sends)  # the window, kept sorted
    assert measured >= (len(stream) - 1) // 20 - 2


def test_the_sums_stay_exact_over_a_long_run() -> None:
    """Hours of poses: the running sums are renewed, so rounding does not pile up."""
    watch = LinkWatch(0.1)
    for k in range(50 * WINDOW):
        sent = 1e5 + k * 0.05
        watch.observe(sent + 0.03 + (0.004 if k % 3 else -0.002), sent)
    expect = straightforward(list(watch._gaps), watch.stale_after, watch.ceiling)
    assert watch.sigma == pytest.approx(expect[2], rel=1e-9)

"""The clock-model estimator: recovers a known offset and drift from synthetic exchanges."""

from __future__ import annotations

import random
from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from federation.core.clockfilter import ClockFilter, Fit
from federation.core.estimators import ESTIMATORS, make_estimator
from federation.core.sync import Exchange, PaperEstimator


def exchanges(
    offset: float,
    drift_ppm: float,
    seconds: float,
    delay: float = 0.040,
    jitter: float = 0.0,
    asymmetry: float = 0.0,
    seed: int = 7,
    period: float = 0.1,
) -> list[Exchange]:
    rng = random.Random(seed)
    rate = 1 + drift_ppm * 1e-6
    out = []
    for k in range(int(seconds / period)):
        t1 = k * period
        arrival = t1 + delay + abs(rng.gauss(0, jitter))
        t3 = arrival + delay + asymmetry + abs(rng.gauss(0, jitter))
        out.append(Exchange(t1, offset + arrival * rate, t3))
    return out


def true_offset(offset: float, drift_ppm: float, t: float) -> float:
    return offset + t * drift_ppm * 1e-6


def test_exact_offset_without_jitter() -> None:
    f = ClockFilter()
    for ex in exchanges(26.42, 0.0, 30):
        f.add(ex)
    assert f.offset == pytest.approx(26.42, abs=1e-9)
    assert f.drift == 0.0
    assert f.bound == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("drift_ppm", [50.0, -50.0, 200.0])
def test_recovers_drift_and_offset_now(drift_ppm: float) -> None:
    f = ClockFilter()
    data = exchanges(-26.42, drift_ppm, 120)
    for ex in data:
        f.add(ex)
    assert f.drift is not None
    assert f.drift * 1e6 == pytest.approx(drift_ppm, abs=0.5)
    t = data[-1].t3
    assert f.offset_at(t) == pytest.approx(true_offset(-26.42, drift_ppm, t), abs=20e-6)
    # Extrapolating 10 s ahead follows the drift; a held constant would not.
    assert f.offset_at(t + 10) == pytest.approx(true_offset(-26.42, drift_ppm, t + 10), abs=50e-6)


def test_jitter_is_filtered_far_better_than_the_paper_mean() -> None:
    data = exchanges(26.42, 50.0, 300, jitter=0.010)
    f, mean = ClockFilter(), PaperEstimator("mean")
    for ex in data:
        f.add(ex)
        mean.add(ex)
    t = data[-1].t3
    truth = true_offset(26.42, 50.0, t)
    ours, papers = abs(f.offset_at(t) - truth), abs(mean.offset_at(t) - truth)  # type: ignore[operator]
    assert ours < 0.5e-3
    assert papers > 10e-3  # 50 ppm over ~290 s: the held mean is ~14 ms behind
    assert ours < papers / 20


def test_insignificant_drift_is_dropped() -> None:
    f = ClockFilter()
    for ex in exchanges(1.0, 0.0, 120, jitter=0.005):
        f.add(ex)
    assert f.drift == 0.0


def test_asymmetry_is_invisible_and_bounded() -> None:
    """A path 10 ms slower back shifts every estimator by half of it: no method sees it."""
    data = exchanges(5.0, 0.0, 60, asymmetry=0.010)
    for name in ESTIMATORS:
        est = make_estimator(name)
        for ex in data:
            est.add(ex)
        error = est.offset_at(data[-1].t3) - 5.0  # type: ignore[operator]
        assert error == pytest.approx(-0.005, abs=1e-6), name
        assert abs(error) <= data[-1].error_bound


def test_window_forgets_old_samples() -> None:
    f = ClockFilter(horizon=20.0)
    for ex in exchanges(1.0, 0.0, 30):
        f.add(ex)
    late = [Exchange(ex.t1 + 30, ex.t2 + 30 + 0.5, ex.t3 + 30) for ex in exchanges(0, 0, 30)]
    for ex in late:
        f.add(ex)
    assert f.offset == pytest.approx(0.5, abs=1e-9)  # the 1.0 s era is gone


def test_locked_after_the_sync_phase_and_reset() -> None:
    f = ClockFilter(lock_after=10.0)
    data = exchanges(0.0, 0.0, 15)
    for ex in data[:50]:
        f.add(ex)
    assert not f.locked
    for ex in data[50:]:
        f.add(ex)
    assert f.locked
    f.reset()
    assert f.offset is None and f.offset_at(1.0) is None and not f.locked


def test_four_timestamps_remove_server_turnaround() -> None:
    # Server holds each request 30 ms before replying: the three-tag delay is inflated.
    ex = Exchange(t1=10.0, t2=36.46, t3=10.11, t2s=36.49)
    assert ex.rtt == pytest.approx(0.08)
    assert ex.delay == pytest.approx(0.04)
    assert ex.offset == pytest.approx(26.42)
    three = Exchange(10.0, 36.46, 10.11)
    assert three.delay == pytest.approx(0.055)
    assert three.offset == pytest.approx(26.405)


@pytest.mark.parametrize("bad", [{"horizon": 0}, {"min_span": -1}])
def test_bad_parameters(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        ClockFilter(**bad)


def test_unknown_estimator() -> None:
    with pytest.raises(ValueError, match="clockfilter"):
        make_estimator("kalman")


class _DequeFilter(ClockFilter):
    """The window as it was before issue 17: a deque of tuples, converted at each fit."""

    def reset(self) -> None:
        super().reset()
        self._tuples: deque[tuple[float, float, float]] = deque()

    def add(self, exchange: Exchange) -> None:
        self._tuples.append((exchange.t_mid, exchange.offset, exchange.rtt))
        while self._tuples and exchange.t_mid - self._tuples[0][0] > self.horizon:
            self._tuples.popleft()
        super().add(exchange)

    def _compute(self) -> Fit | None:
        rows = self._window.rows()
        assert np.array_equal(rows, np.asarray(self._tuples).reshape(-1, 3))  # the same window
        return super()._compute()


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(0.01, 3.0),  # seconds since the previous exchange
            st.floats(0.0, 0.05),  # round trip
            st.floats(-0.01, 0.01),  # offset noise
        ),
        min_size=1,
        max_size=400,
    ),
    st.sampled_from([5.0, 30.0, 120.0]),
)
def test_the_array_window_holds_what_the_deque_held(
    steps: list[tuple[float, float, float]], horizon: float
) -> None:
    """Rows appended, dropped, moved back and grown: always the horizon's exchanges in
    order, and the fits those of the straightforward window."""
    ours, theirs = ClockFilter(horizon=horizon), _DequeFilter(horizon=horizon)
    t = 1000.0
    for dt, rtt, noise in steps:
        t += dt
        ex = Exchange(t, t + rtt / 2 + 3.0 + noise, t + rtt)
        ours.add(ex)
        theirs.add(ex)
        assert ours.fit == theirs.fit
        assert ours.locked == theirs.locked

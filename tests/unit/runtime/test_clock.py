"""Execution clock (federation/clock.py), driven by a fake host source."""

from __future__ import annotations

import math
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.runtime.clock import ExecClock


class FakeSource:
    """A host clock the test sets by hand; counts how often it is read."""

    def __init__(self, now: float = 1000.0):
        self.now = now
        self.reads = 0

    def __call__(self) -> float:
        self.reads += 1
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def test_starts_at_zero_by_default() -> None:
    source = FakeSource(12345.0)
    clock = ExecClock(source=source)
    assert clock.now() == 0.0
    source.advance(2.5)
    assert clock.now() == 2.5


def test_starts_at_offset() -> None:
    source = FakeSource(500.0)
    clock = ExecClock(offset=26.42, source=source)
    assert clock.now() == 26.42
    source.advance(1.0)
    assert clock.now() == pytest.approx(27.42, abs=1e-12)


def test_negative_offset() -> None:
    source = FakeSource(0.0)
    clock = ExecClock(offset=-30.88, source=source)
    assert clock.now() == -30.88
    source.advance(40.0)
    assert clock.now() == pytest.approx(9.12, abs=1e-12)


def test_start_is_the_source_reading_at_construction() -> None:
    source = FakeSource(77.0)
    clock = ExecClock(source=source)
    assert clock.start == 77.0
    assert source.reads == 1
    source.advance(100.0)
    assert clock.start == 77.0


def test_at_maps_host_readings() -> None:
    clock = ExecClock(offset=10.0, source=FakeSource(100.0))
    assert clock.at(100.0) == 10.0
    assert clock.at(103.5) == 13.5
    assert clock.at(99.0) == 9.0  # before the start: earlier execution time


@pytest.mark.parametrize("ppm", [100.0, -100.0, 1.0, 50_000.0])
def test_drift_in_ppm(ppm: float) -> None:
    source = FakeSource(0.0)
    clock = ExecClock(offset=5.0, drift_ppm=ppm, source=source)
    assert clock.rate == pytest.approx(1.0 + ppm / 1e6, rel=1e-15)
    source.advance(1000.0)
    # 1000 s of host time gain ppm * 1e-6 * 1000 s extra.
    assert clock.now() == pytest.approx(5.0 + 1000.0 + ppm * 1e-3, abs=1e-9)


def test_drift_hand_computed() -> None:
    source = FakeSource(0.0)
    clock = ExecClock(drift_ppm=250.0, source=source)  # 250 ppm: 0.25 ms per second
    source.advance(3600.0)
    assert clock.now() == pytest.approx(3600.9, abs=1e-9)


def test_drift_does_not_move_the_start() -> None:
    source = FakeSource(50.0)
    clock = ExecClock(offset=1.5, drift_ppm=1000.0, source=source)
    assert clock.now() == 1.5


def test_read_returns_consistent_pair() -> None:
    source = FakeSource(200.0)
    clock = ExecClock(offset=3.0, drift_ppm=10.0, source=source)
    source.advance(7.25)
    reads = source.reads
    exec_time, host = clock.read()
    assert source.reads == reads + 1  # one reading: both values from the same instant
    assert host == 207.25
    assert exec_time == clock.at(host)
    assert exec_time == pytest.approx(3.0 + 7.25 * (1 + 10e-6), abs=1e-12)


def test_read_pair_is_consistent_even_if_the_source_moves_between_reads() -> None:
    readings = iter([0.0, 1.0, 2.0, 3.0])
    clock = ExecClock(offset=100.0, source=lambda: next(readings))
    exec_time, host = clock.read()
    assert host == 1.0
    assert exec_time == 101.0
    assert clock.now() == 102.0


@given(
    offset=st.floats(-1e6, 1e6),
    ppm=st.floats(-5e4, 5e4),
    elapsed=st.floats(0.0, 1e5),
)
def test_clock_formula(offset: float, ppm: float, elapsed: float) -> None:
    source = FakeSource(1.0e4)
    clock = ExecClock(offset=offset, drift_ppm=ppm, source=source)
    source.advance(elapsed)
    expected = offset + elapsed * (1.0 + ppm * 1e-6)
    assert clock.now() == pytest.approx(expected, rel=1e-9, abs=1e-6)


@given(st.lists(st.floats(0.0, 1e3), min_size=2, max_size=20))
def test_clock_is_monotonic_with_a_monotonic_source(steps: list[float]) -> None:
    source = FakeSource(0.0)
    clock = ExecClock(offset=-5.0, drift_ppm=-500.0, source=source)
    previous = clock.now()
    for step in steps:
        source.advance(step)
        current = clock.now()
        assert current >= previous
        previous = current


@pytest.mark.parametrize("offset", [math.nan, math.inf, -math.inf])
def test_rejects_non_finite_offset(offset: float) -> None:
    with pytest.raises(ValueError, match="offset"):
        ExecClock(offset=offset, source=FakeSource())


@pytest.mark.parametrize("ppm", [math.nan, math.inf, -math.inf, 1e5, -1e5, 2e5])
def test_rejects_bad_drift(ppm: float) -> None:
    with pytest.raises(ValueError, match="drift"):
        ExecClock(drift_ppm=ppm, source=FakeSource())


def test_drift_just_below_limit_accepted() -> None:
    assert ExecClock(drift_ppm=99_999.0, source=FakeSource()).rate == pytest.approx(1.099999)
    assert ExecClock(drift_ppm=-99_999.0, source=FakeSource()).rate == pytest.approx(0.900001)


def test_default_source_is_monotonic() -> None:
    clock = ExecClock(offset=10.0)
    assert clock.source is time.monotonic
    first = clock.now()
    assert 10.0 <= first < 20.0  # just started
    assert clock.now() >= first

"""FloatRing: the last N floats in one buffer (an agent's control-tick lateness)."""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core.ring import FloatRing
from federation.runtime.status import loop_stats


@given(st.lists(st.floats(-1e3, 1e3), max_size=40), st.integers(1, 9))
def test_it_holds_the_last_values_as_a_bounded_deque_would(values: list[float], size: int) -> None:
    ring, recent = FloatRing(size), deque[float](maxlen=size)
    for value in values:
        ring.append(value)
        recent.append(value)
        assert len(ring) == len(recent)
        assert list(ring) == list(recent)  # oldest first
        assert sorted(ring.values().tolist()) == sorted(recent)


def test_an_empty_ring_holds_nothing_and_a_ring_of_nothing_is_refused() -> None:
    ring = FloatRing(3)
    assert len(ring) == 0 and list(ring) == [] and ring.values().tolist() == []
    with pytest.raises(ValueError, match="at least 1"):
        FloatRing(0)


@given(st.lists(st.floats(0.0, 0.05), max_size=300))
def test_loop_stats_read_from_the_ring_equal_those_of_the_values(lateness: list[float]) -> None:
    ring = FloatRing(200)
    for value in lateness:
        ring.append(value)
    assert loop_stats(20.0, ring.values()) == loop_stats(20.0, lateness[-200:])


def test_the_values_are_a_read_only_view_and_loop_stats_wants_doubles() -> None:
    ring = FloatRing(4)
    ring.append(0.001)
    view = ring.values()
    with pytest.raises(TypeError):
        view[0] = 1.0  # type: ignore[index]
    with pytest.raises(TypeError, match="format 'd'"):
        loop_stats(20.0, memoryview(bytes(8)))

"""Own clock, reference time and a peer's clock (federation/core/timebase.py)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from federation.core.timebase import TimeBase


@dataclass
class Fixed:
    """An estimate with an offset and a drift (peer minus own, s and s/s)."""

    offset: float | None
    drift: float = 0.0

    def offset_at(self, t: float) -> float | None:
        return None if self.offset is None else self.offset + self.drift * t


def test_the_reference_itself_has_simulation_time_on_its_clock() -> None:
    base = TimeBase("ref", "ref", {"b": Fixed(2.0)})
    assert base.reference_offset(10.0) == 0.0
    assert base.sim_time(10.0) == 10.0
    assert base.peer_time("b", 10.0) == 12.0
    assert base.peer_to_sim("b", 12.0, 10.0) == 10.0


def test_a_follower_maps_through_the_reference_estimate() -> None:
    # Reference 26.42 s ahead of me, peer c 1 s behind me.
    base = TimeBase("me", "ref", {"ref": Fixed(26.42), "c": Fixed(-1.0)})
    assert base.sim_time(100.0) == pytest.approx(126.42)  # Eq. 5
    assert base.peer_time("c", 100.0) == pytest.approx(99.0)
    # A sample c stamped 98.9 on its clock happened at 99.9 on mine: 126.32 on reference time.
    assert base.peer_to_sim("c", 98.9, 100.0) == pytest.approx(126.32)
    assert base.peer_to_sim("ref", 126.0, 100.0) == pytest.approx(126.0)
    assert base.offset("me", 100.0) == 0.0


def test_estimates_are_evaluated_at_the_own_time_given() -> None:
    base = TimeBase("me", "ref", {"ref": Fixed(1.0, drift=1e-4)})
    assert base.sim_time(0.0) == pytest.approx(1.0)
    assert base.sim_time(1000.0) == pytest.approx(1001.1)


def test_missing_estimates_give_none() -> None:
    base = TimeBase("me", "ref", {"c": Fixed(None), "d": Fixed(0.5)})
    assert base.sim_time(1.0) is None  # no reference estimate
    assert base.peer_time("c", 1.0) is None  # an estimate not ready
    assert base.peer_time("x", 1.0) is None  # an unknown peer
    assert base.peer_to_sim("d", 1.0, 1.0) is None  # d known, the reference not


def test_the_table_is_read_live() -> None:
    peers: dict[str, Fixed] = {}
    base = TimeBase("me", "ref", peers)
    assert base.sim_time(1.0) is None
    peers["ref"] = Fixed(3.0)
    assert base.sim_time(1.0) == 4.0

"""How far ahead ctl announces a freeze or resume (federation/core/lead.py)."""

from __future__ import annotations

import pytest

from federation.core.lead import (
    LEAD_FACTOR,
    LEAD_MARGIN,
    UNKNOWN_DELAY,
    Lead,
    delays_to,
    transition_lead,
)


def test_the_delays_are_each_participants_to_the_reference_as_its_status_says() -> None:
    statuses = {
        "kiruna/knatte": {"peers": {}},
        "rome/pinocchio": {"peers": {"kiruna/knatte": {"delay": 0.040}}},
        "rome/geppetto": {"peers": {"kiruna/knatte": {"delay": None}}},
        "rome/bad": {"peers": {"kiruna/knatte": {"delay": True}}},
    }
    delays = delays_to("kiruna/knatte", [*statuses, "rome/absent"], statuses)
    assert delays == {
        "kiruna/knatte": 0.0,  # the reference itself
        "rome/pinocchio": 0.040,
        "rome/geppetto": None,
        "rome/bad": None,
        "rome/absent": None,
    }


def test_the_lead_covers_the_slowest_path_twice_with_margin() -> None:
    # Kiruna to Rome 40 ms one way, ctl 1 ms from the reference: the paper's labs.
    lead = transition_lead({"kiruna/knatte": 0.0, "rome/pinocchio": 0.040}, 0.001)
    assert lead == Lead(LEAD_MARGIN + LEAD_FACTOR * 0.041, "rome/pinocchio", 0.041)
    assert lead.seconds == pytest.approx(0.332)
    assert lead.describe() == "0.332 s ahead (slowest path: to rome/pinocchio, 41.0 ms one way)"


def test_a_participant_whose_delay_is_not_known_counts_as_slow_and_is_named() -> None:
    lead = transition_lead({"kiruna/knatte": 0.0, "rome/pinocchio": None}, 0.002)
    assert lead.worst == "rome/pinocchio" and lead.unknown == ("rome/pinocchio",)
    assert lead.seconds == pytest.approx(LEAD_MARGIN + LEAD_FACTOR * (UNKNOWN_DELAY + 0.002))
    assert "delay not known for rome/pinocchio" in lead.describe()


def test_without_participants_the_lead_is_ctls_own_path_with_margin() -> None:
    lead = transition_lead({}, 0.01)
    assert (lead.seconds, lead.worst) == (pytest.approx(LEAD_MARGIN + LEAD_FACTOR * 0.01), None)

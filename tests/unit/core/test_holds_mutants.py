"""The safety supervisor (federation/core/holds.py): what its Change says, the table's
rows as records, and the table as operators read it. Each closes a gap that mutation
testing showed (docs/mutation.md)."""

from __future__ import annotations

import dataclasses

import hypothesis.strategies as st
import pytest
from hypothesis import given

from federation.core.holds import RULES, Hold, Supervisor, Trigger, holds_table_markdown


@given(st.frozensets(st.sampled_from(list(Hold))), st.sampled_from(list(Trigger)))
def test_a_change_names_exactly_the_holds_it_set_and_lifted(
    standing: frozenset[Hold], trigger: Trigger
) -> None:
    # "the holds it set and lifted (each only if it changed)": a hold standing before and
    # after is in neither.
    s = Supervisor(standing)
    change = s.apply(trigger)
    assert change.trigger is trigger
    assert change.set == s.standing - standing
    assert change.lifted == standing - s.standing


def test_a_trigger_again_changes_nothing() -> None:
    s = Supervisor(())
    assert s.apply(Trigger.LINK_STALE).set == {Hold.STALE}
    again = s.apply(Trigger.LINK_STALE)
    assert (again.set, again.lifted) == (frozenset(), frozenset())
    assert s.standing == {Hold.STALE}
    s.apply(Trigger.LINK_RESUMED)
    assert s.apply(Trigger.LINK_RESUMED).lifted == frozenset() and s.may_open


def test_the_table_and_its_changes_cannot_be_altered() -> None:
    # One table decides every hold: no code can turn a row's preflight off, or rewrite
    # what a change reported, after the fact.
    with pytest.raises(dataclasses.FrozenInstanceError):
        RULES[0].preflight = False  # type: ignore[misc]
    change = Supervisor().apply(Trigger.RUN_STARTED)
    with pytest.raises(dataclasses.FrozenInstanceError):
        change.lifted = frozenset()  # type: ignore[misc]


def test_the_operators_table_has_one_row_per_hold_in_rank_order() -> None:
    header, rule, *rows = holds_table_markdown().splitlines()
    assert header.startswith("| hold |") and set(rule) <= {"|", "-"}
    assert len(rows) == len(RULES)
    for row, r in zip(rows, RULES, strict=True):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[:2] == [f"`{r.hold.value}`", f"`{r.set_by.value}`"]
        lifted = sorted(t.value for t in r.lifted_by)
        assert cells[2] == (", ".join(lifted) if lifted else "nothing")
        assert cells[3:5] == [r.release.value, "yes" if r.preflight else "no"]
        assert cells[5:] == [r.meaning]

"""The command gate (federation/core/commands.py): per-issuer order, aborts always."""

from __future__ import annotations

import pytest

from federation.core.commands import MAX_JUMP, MAX_SEQ, CommandGate


def test_an_issuers_commands_in_order_are_admitted_and_repeats_are_not() -> None:
    gate = CommandGate()
    assert gate.admit("start", "ctl@a", 1).admitted
    assert gate.admit("start", "ctl@a", 1).outcome == "repeat"
    assert gate.admit("freeze", "ctl@a", 2).admitted
    assert gate.admit("resume", "ctl@a", 1).outcome == "stale"


@pytest.mark.parametrize("seq", [10**30, -1, MAX_SEQ + 1])
def test_abort_is_admitted_whatever_its_seq(seq: int) -> None:
    gate = CommandGate()
    gate.admit("start", "ctl@a", 5)
    assert gate.admit("abort", "ctl@a", seq).admitted
    assert gate.admit("abort", "ctl@a", seq).admitted  # again: the run state makes it harmless
    assert gate.admit("abort", "ctl@a", 0).admitted  # lower than the issuer's last


def test_a_huge_seq_is_out_of_range_and_poisons_nothing() -> None:
    gate = CommandGate()
    verdict = gate.admit("resume", "ctl", 10**30)
    assert (
        verdict.outcome == "seq out of range"
        and "1000000000000000000000000000000" in verdict.detail
    )
    assert gate.admit("start", "ctl", 1).admitted  # the same issuer's next command
    assert gate.admit("start", "ctl@b", 1).admitted  # any other issuer


def test_a_jump_is_dropped_and_does_not_become_the_issuers_last() -> None:
    gate = CommandGate()
    gate.admit("start", "op", 3)
    verdict = gate.admit("resume", "op", 3 + MAX_JUMP + 1)
    assert verdict.outcome == "seq jumped"
    assert gate.admit("freeze", "op", 4).admitted


def test_one_issuers_commands_do_not_order_anothers() -> None:
    """Two operators whose counters (or clocks) differ by far: both act."""
    gate = CommandGate()
    assert gate.admit("start", "ctl@fast-clock", 1_700_000_030_000).admitted
    assert gate.admit("freeze", "ctl@slow-clock", 1_700_000_000_000).admitted
    assert gate.admit("resume", "ctl@new", 1).admitted


def test_the_issuer_table_is_bounded() -> None:
    gate = CommandGate(max_issuers=4)
    for i in range(100):
        gate.admit("start", f"forged-{i}", 1)
    assert len(gate.last) == 4
    assert list(gate.last) == [f"forged-{i}" for i in range(96, 100)]


def test_an_abort_with_a_wild_seq_does_not_silence_its_issuer() -> None:
    gate = CommandGate()
    assert gate.admit("start", "ops", 1).admitted
    assert gate.admit("abort", "ops", 10**9).admitted  # acted on
    assert gate.admit("reset", "ops", 2).admitted  # and the issuer's next still is
    assert gate.admit("start", "ops", 3).admitted
    assert gate.admit("abort", "ops", 4).admitted
    assert gate.admit("reset", "ops", 4).outcome == "repeat"  # in order: remembered

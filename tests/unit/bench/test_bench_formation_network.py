"""The formation-in-the-testbed benchmark's transparency ratio
(federation/bench/formation_network.py ``ratios``), on made-up run results: each
repeat's error under loss over the same repeat's with no loss, their median and spread,
and what a failed run or bad input does."""

from __future__ import annotations

from typing import Any

import pytest

from federation import cli
from federation.bench.formation_network import after_ramp, ratios


def _run(loss: float, repeat: int, error: float | None) -> dict[str, Any]:
    if error is None:  # a run that failed keeps why, and no figure
        return {"loss": loss, "repeat": repeat, "error": "the run did not end"}
    return {"loss": loss, "repeat": repeat, "error_rms_m": error}


def test_each_repeat_over_its_own_no_loss_run_with_median_and_spread() -> None:
    runs = [
        _run(0.0, 0, 0.10), _run(0.01, 0, 0.11), _run(0.05, 0, 0.15),
        _run(0.0, 1, 0.20), _run(0.01, 1, 0.20), _run(0.05, 1, 0.24),
        _run(0.0, 2, 0.05), _run(0.01, 2, 0.06), _run(0.05, 2, 0.05),
    ]  # fmt: skip
    rows = ratios(runs)
    assert [r["loss"] for r in rows] == [0.01, 0.05]  # no row for the baseline itself
    one, five = rows
    assert one["repeats"] == [0, 1, 2]
    assert one["baseline_m"] == [0.10, 0.20, 0.05]
    assert one["error_m"] == [0.11, 0.20, 0.06]
    # Paired by repeat: 0.11/0.10, 0.20/0.20, 0.06/0.05 (not 0.11 over the median 0.10).
    assert one["ratio"] == pytest.approx([1.1, 1.0, 1.2])
    assert one["ratio_stats"] == pytest.approx({"median": 1.1, "min": 1.0, "max": 1.2})
    assert five["ratio"] == pytest.approx([1.5, 1.2, 1.0])
    assert five["ratio_stats"] == pytest.approx({"median": 1.2, "min": 1.0, "max": 1.5})


def test_the_order_of_runs_does_not_matter() -> None:
    runs = [_run(0.05, 1, 0.3), _run(0.0, 1, 0.2), _run(0.0, 0, 0.1), _run(0.05, 0, 0.1)]
    assert ratios(runs) == ratios(list(reversed(runs)))
    assert ratios(runs)[0]["ratio"] == pytest.approx([1.0, 1.5])


def test_a_failed_run_has_no_ratio_and_leaves_the_others() -> None:
    runs = [
        _run(0.0, 0, 0.10), _run(0.05, 0, None),  # the lossy run failed
        _run(0.0, 1, None), _run(0.05, 1, 0.30),  # its baseline failed
        _run(0.0, 2, 0.10), _run(0.05, 2, 0.12),
    ]  # fmt: skip
    (row,) = ratios(runs)
    assert row["ratio"][:2] == [None, None]
    assert row["ratio"][2] == pytest.approx(1.2)
    assert row["ratio_stats"] == pytest.approx({"median": 1.2, "min": 1.2, "max": 1.2})


def test_no_ratio_at_all_is_none_not_a_number() -> None:
    (row,) = ratios([_run(0.0, 0, 0.0), _run(0.01, 0, 0.1)])  # a zero baseline
    assert row["ratio"] == [None]
    assert row["ratio_stats"] == {"median": None, "min": None, "max": None}


def test_a_repeat_missing_at_one_loss_has_no_ratio_there() -> None:
    (row,) = ratios([_run(0.0, 0, 0.1), _run(0.0, 1, 0.1), _run(0.05, 1, 0.2)])
    assert row["error_m"] == [None, 0.2]
    assert row["ratio"] == [None, pytest.approx(2.0)]


def test_ratios_of_another_figure_read_that_figure() -> None:
    runs = [
        {"loss": 0.0, "repeat": 0, "error_rms_m": 0.09, "error_rms_after_ramp_m": 0.010},
        {"loss": 0.05, "repeat": 0, "error_rms_m": 0.09, "error_rms_after_ramp_m": 0.013},
    ]
    (whole,) = ratios(runs)
    (circle,) = ratios(runs, "error_rms_after_ramp_m")
    assert whole["ratio"] == pytest.approx([1.0]) and whole["figure"] == "error_rms_m"
    assert circle["ratio"] == pytest.approx([1.3])
    assert circle["figure"] == "error_rms_after_ramp_m"


def test_after_ramp_is_the_rms_over_every_platform_from_the_end_of_the_ramp() -> None:
    spec = {"formation": {"still": 1.0, "ramp": 1.0}}
    formation = {
        "series": {
            "run_time_s": [0.0, 1.0, 1.9, 2.0, 3.0],
            "error_m": {"a": [9.0, 9.0, 9.0, 3.0, 0.0], "b": [9.0, 9.0, 9.0, 4.0, 0.0]},
        }
    }
    # From 2.0 s on: a's 3 and 0, b's 4 and 0; sqrt((9 + 0 + 16 + 0) / 4) = 2.5.
    assert after_ramp(formation, spec) == pytest.approx(2.5)
    short = {"series": {"run_time_s": [0.0, 1.5], "error_m": {"a": [1.0, 1.0]}}}
    assert after_ramp(short, spec) is None  # the run ended before the circle


def test_results_without_loss_or_repeat_or_twice_the_same_are_refused() -> None:
    with pytest.raises(ValueError, match=r"result 1: needs 'loss' and 'repeat'"):
        ratios([_run(0.0, 0, 0.1), {"loss": 0.05, "error_rms_m": 0.2}])
    with pytest.raises(ValueError, match=r"result 2: a second run at loss 0.05, repeat 0"):
        ratios([_run(0.0, 0, 0.1), _run(0.05, 0, 0.2), _run(0.05, 0, 0.3)])


@pytest.mark.parametrize(
    ("value", "why"),
    [("1.5", "1.5: a loss is a fraction from 0 to below 1"), ("lots", "'lots' is not a number")],
)
def test_the_command_refuses_a_loss_that_is_no_fraction(
    value: str, why: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["bench", "network-formation", "--loss", value])
    assert exit_.value.code == 2
    assert f"--loss: {why}" in capsys.readouterr().err

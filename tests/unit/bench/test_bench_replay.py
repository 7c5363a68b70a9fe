"""``fedlab bench replay``'s pure parts: the heading RMS error over a window
(:mod:`federation.report.tracking`) on synthetic headings, the maneuver flown and its
window, the experiments it writes, the verdict on a result and the argument checks."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from federation import cli
from federation.bench import replay
from federation.report.tracking import heading_error
from schemas.experiment import load_experiment

T = np.arange(0.0, 20.0, 0.05)  # 20 Hz poses over 20 s of run time


def test_a_constant_error_is_its_own_rms() -> None:
    led = np.radians(30.0) * np.sin(T / 3)
    got = heading_error(T, led + np.radians(1.5), T, led, (2.0, 18.0))
    assert got.rms_deg == pytest.approx(1.5, abs=1e-9)
    assert got.poses == 321  # 2.00 to 18.00 s inclusive at 20 Hz


def test_a_lag_on_a_ramp_is_rate_times_lag() -> None:
    rate = np.radians(2.0)  # rad/s: the leader turns 2 deg/s
    lag = 0.25  # s the follower trails
    follower_t = T + 0.013  # sent between the leader's poses: interpolated
    got = heading_error(follower_t, rate * (follower_t - lag), T, rate * T, (1.0, 19.0))
    assert got.rms_deg == pytest.approx(2.0 * lag, abs=1e-9)


def test_headings_are_unwrapped_across_pi() -> None:
    # Both turn through +-180 deg; wrapped, the raw difference would jump by 360 deg.
    led = np.radians(170.0) + np.radians(1.0) * T
    wrap = (led + np.pi) % (2 * np.pi) - np.pi
    follow = (led + np.radians(0.5) + np.pi) % (2 * np.pi) - np.pi
    assert heading_error(T, follow, T, wrap, (0.0, 19.0)).rms_deg == pytest.approx(0.5, abs=1e-9)


def test_only_the_window_counts() -> None:
    led = np.zeros_like(T)
    follow = np.where((T >= 5.0) & (T <= 10.0), np.radians(1.0), np.radians(90.0))
    assert heading_error(T, follow, T, led, (5.0, 10.0)).rms_deg == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("window", "t_leader", "message"),
    [
        ((5.0, 5.0), T, "its start must come before its end"),
        ((18.0, 19.0), T, "21 follower poses in the window 18 to 19 s of run time"),
        ((1.0, 10.0), T[:1], "1 leader poses: at least 2"),
    ],
)
def test_what_cannot_be_scored_is_refused_saying_why(
    window: tuple[float, float], t_leader: np.ndarray, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        heading_error(T, np.zeros_like(T), t_leader, np.zeros_like(t_leader), window)


def test_the_paper_maneuver_in_the_demo_run() -> None:
    m = replay.maneuver(None)
    assert (m.still, m.duration, m.amplitude_deg, m.run_s) == (10.0, 60.0, 45.0, 75.0)
    assert m.window == (10.2, 70.0)
    short = replay.maneuver(4.0)
    assert (short.still, short.run_s, short.window) == (0.5, 5.0, (0.7, 4.5))
    with pytest.raises(ValueError, match="at least 1 s"):
        replay.maneuver(0.5)


def test_the_experiments_it_writes_load(tmp_path: Path) -> None:
    live = tmp_path / "live.toml"
    live.write_text(replay.experiment_toml(replay.PAPER, "x", replay.LEADER, replay.FOLLOWER))
    exp = load_experiment(live)
    assert exp.duration == 75.0 and exp.maneuver.duration == 60.0
    assert [(p.agent, p.role, p.platform) for p in exp.participants] == [
        (replay.LEADER, "leader", "knatte"),
        (replay.FOLLOWER, "follower", "pinocchio"),
    ]
    assert exp.participants[1].latency_compensation  # the default
    ref = tmp_path / "ref.toml"
    ref.write_text(replay.experiment_toml(replay.PAPER, "x", replay.FOLLOWER, None))
    assert [p.agent for p in load_experiment(ref).participants] == [replay.FOLLOWER]


def _repeat(k: int, live: float, replayed: float) -> dict[str, Any]:
    return {"repeat": k, "rms_live_deg": live, "rms_replayed_deg": replayed,
            "ratio": replayed / live}  # fmt: skip


def test_a_ratio_past_the_bound_or_a_failed_repeat_is_named() -> None:
    repeats = [_repeat(0, 1.0, 1.2), _repeat(1, 1.0, 1.6), {"repeat": 2, "error": "x\nlog"}]
    result: dict[str, Any] = {"repeats": repeats, "summary": replay.summary(repeats)}
    assert replay.failures(result) == [
        "repeat 1: ratio 1.600 exceeds 1.5 (1.6000 deg replayed, 1.0000 live)",
        "repeat 2 failed: x",
    ]
    assert result["summary"]["ratio"] == {"median": 1.4, "min": 1.2, "max": 1.6}
    assert result["summary"]["repeats_failed"] == 1
    assert replay.failures({"repeats": repeats[:1]}) == []
    assert math.isclose(replay.BOUND, 1.5)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--repeats", "0"], "--repeats: at least 1"),
        (["--delay-ms", "-1"], "--delay-ms: must be a number >= 0"),
        (["--maneuver-seconds", "0.5"], "maneuver of 0.5 s: at least 1 s"),
        (["--sync-window", "0"], "sync window 0 s: must be positive"),
    ],
)
def test_bad_arguments_are_refused_before_anything_starts(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        code = cli.main(["bench", "replay", *args])
        raise SystemExit(code)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err

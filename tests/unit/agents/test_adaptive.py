"""Adaptive gains (agents/adaptive.py)."""

from __future__ import annotations

import math

import pytest

from agents.adaptive import AdaptiveGains
from agents.control import HeadingPid
from schemas.scenario import AdaptiveConfig


def test_schedule_follows_the_leaders_peak_rate_over_the_window() -> None:
    pid = HeadingPid(0.2, 0.02, 0.3, 0.1, 0.01)
    gains = AdaptiveGains(AdaptiveConfig(nominal_rate_deg=2.0, max_scale=3.0, window=10.0), pid)
    assert gains.observe(0.0, math.radians(1.0)) == 1.0  # quiet leader: the preset's gains
    assert (pid.kp, pid.ki, pid.kd) == (0.2, 0.02, 0.3)
    assert gains.observe(1.0, math.radians(-4.0)) == pytest.approx(2.0)
    assert (pid.kp, pid.ki, pid.kd) == pytest.approx((0.8, 0.16, 0.6))
    assert gains.observe(1.0, math.radians(10.0)) == pytest.approx(2.0)  # same stamp: ignored
    assert gains.observe(5.0, math.radians(20.0)) == 3.0  # capped
    assert gains.observe(14.0, 0.0) == 3.0  # the peak at 5 s is still in the window
    assert gains.observe(16.0, 0.0) == 1.0  # not any more

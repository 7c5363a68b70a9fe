"""The report's figure helpers on hand-made series."""

from __future__ import annotations

import warnings

import numpy as np

from federation.report.analysis import Follow
from federation.report.figures import _steepest


def _follow(t: np.ndarray, h: np.ndarray) -> Follow:
    empty = np.array([])
    return Follow(
        follower="rome/pinocchio", leader="kiruna/knatte", compensation=True,
        sent=(t, h), leader_heading=(t, h), leader_reference=(t, h), received=None,
        received_time="truth", reference=None, heading=None, window=None, start=0.0,
        pose_received=0, pose_age=empty,
    )  # fmt: skip


def test_the_fastest_turn_is_found_past_samples_on_one_instant() -> None:
    # The heading turns fastest at 6 s; at 2 s two samples share an instant (a frozen
    # run's, a repeated stamp), which would make the gradient infinite there.
    t = np.arange(0.0, 10.0, 0.1)
    h = 0.3 * np.tanh(3.0 * (t - 6.0))
    t = np.insert(t, 21, t[20])
    h = np.insert(h, 21, h[20] + 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division by zero on the way
        assert abs(_steepest(_follow(t, h)) - 6.0) < 0.051

"""How closely a follower's heading tracked a leader's, from their two recordings.

A follower tracks the leader's heading; the error at each pose the follower sent in a
run is its heading minus the leader's heading sent at the same run time (linearly
interpolated between the leader's poses), both unwrapped. The figure is the RMS of that
error over a window of run time (the maneuver), in degrees:

.. math::  e_{rms} = \\sqrt{\\tfrac{1}{n} \\sum_{t_i \\in W} (h_f(t_i) - h_l(t_i))^2}

The same figure judges a follower flown against a live leader and against that
leader's replay (``fedlab replay``), so the two can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from federation.runtime.replayfile import Recording

__all__ = ["MIN_POSES", "HeadingError", "heading_error", "recorded_error"]

MIN_POSES = 41
"""Poses a follower must have sent inside the window for an RMS to mean anything (over 2 s
of poses at 20 Hz)."""


@dataclass(frozen=True)
class HeadingError:
    """The RMS heading error (deg) over a window and the follower's poses it counts."""

    rms_deg: float
    poses: int


def heading_error(
    t: ArrayLike,
    heading: ArrayLike,
    t_leader: ArrayLike,
    heading_leader: ArrayLike,
    window: tuple[float, float],
    min_poses: int = MIN_POSES,
) -> HeadingError:
    """The follower's heading (rad, at run times ``t``) minus the leader's (rad, at run
    times ``t_leader``, ascending) over ``window`` (s of run time, inclusive). Raises
    ValueError for a window that is empty or reversed, a leader with fewer than two
    poses, or fewer than ``min_poses`` follower poses inside the window."""
    low, high = window
    if not low < high:
        raise ValueError(f"window {window}: its start must come before its end")
    times, headings = np.asarray(t, dtype=float), np.asarray(heading, dtype=float)
    t_led, h_led = np.asarray(t_leader, dtype=float), np.asarray(heading_leader, dtype=float)
    if times.shape != headings.shape or t_led.shape != h_led.shape:
        raise ValueError("each time series needs one heading per time")
    if len(t_led) < 2:
        raise ValueError(f"{len(t_led)} leader poses: at least 2 are needed to interpolate")
    inside = (times >= low) & (times <= high)
    if int(inside.sum()) < min_poses:
        raise ValueError(
            f"{int(inside.sum())} follower poses in the window {low:g} to {high:g} s of run "
            f"time: at least {min_poses} are needed"
        )
    led = np.interp(times[inside], t_led, np.unwrap(h_led))
    error = np.unwrap(headings)[inside] - led
    return HeadingError(float(np.degrees(np.sqrt(np.mean(error**2)))), int(inside.sum()))


def recorded_error(
    follower: Path,
    leader: Path,
    window: tuple[float, float],
    follower_agent: str,
    leader_agent: str,
    min_poses: int = MIN_POSES,
) -> HeadingError:
    """:func:`heading_error` of the poses ``follower_agent`` sent in its run (recorded
    in ``follower``) against those ``leader_agent`` sent (in ``leader``), on the run
    times each recorded. A ValueError names the file it concerns."""
    led = list(Recording(leader, leader_agent).poses())
    flown = [p for p in Recording(follower, follower_agent).poses() if p.run_time is not None]
    try:
        return heading_error(
            [p.run_time for p in flown], [p.pose.heading for p in flown],
            [p.run_time for p in led], [p.pose.heading for p in led], window, min_poses,
        )  # fmt: skip
    except ValueError as error:
        raise ValueError(f"{follower} against {leader}: {error}") from None

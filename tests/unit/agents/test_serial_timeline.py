"""Which frames of a serial device belong to its clock now (agents/serial/timeline.py).

Pure: device times and the host's time in, verdicts out.
"""

from __future__ import annotations

import pytest

from agents.serial.timeline import DeviceTimeline


def test_frames_on_the_devices_clock_are_taken_once() -> None:
    line = DeviceTimeline(0.5)
    assert line.judge("imu", 10.0, 0.0) == "take"
    assert line.judge("pose", 9.8, 0.0) == "take"  # a POSE lags the IMU by its latency
    assert line.judge("imu", 10.0, 0.0) == "not_newer"  # replayed
    assert line.judge("pose", 9.7, 0.0) == "not_newer"  # reordered
    assert line.judge("status", 10.0, 0.0) == "take"
    assert line.judge("status", 10.0, 0.0) == "take"  # a STATUS at once, at the same time
    assert line.judge("status", 9.99, 0.0) == "not_newer"
    # Ahead by 2 s after the host stalled 2 s (frames lost meanwhile): on it.
    assert line.judge("imu", 12.0, 2.0) == "take"
    assert line.newest == 12.0 and not line.pending
    # A backlog read at once goes on frame by frame: on it too.
    assert all(line.judge("imu", 12.0 + 0.01 * k, 2.0) == "take" for k in range(1, 300))


def test_an_old_frame_is_on_no_timeline_and_a_new_one_ends_its_candidate() -> None:
    line = DeviceTimeline(0.5, confirm=3)
    for k in range(100):
        assert line.judge("imu", 10.0 + 0.01 * k, 0.01 * k) == "take"
    assert line.judge("imu", 11.0, 1.0) == "take"
    assert line.judge("pose", 8.99, 1.0) == "off_timeline"  # a replay, a backlog
    assert line.pending
    assert line.judge("imu", 11.01, 1.01) == "take"
    assert not line.pending
    # Stray old frames that are not one timeline never add up to a restart.
    for t in (3.0, 7.0, 1.0, 5.0, 2.0, 9.0):
        assert line.judge("imu", t, 1.01) == "off_timeline"
    assert line.judge("imu", 11.02, 1.02) == "take"


def test_a_frame_from_the_future_is_on_no_timeline_either() -> None:
    # Its time ahead of the device's clock by more than the host's clock advanced: it
    # once became the newest, and the device's real frames all looked old after it.
    line = DeviceTimeline(0.5, confirm=3)
    assert line.judge("imu", 10.0, 0.0) == "take"
    assert line.judge("pose", 1e9, 0.01) == "off_timeline"
    assert line.judge("imu", 10.01, 0.01) == "take" and line.newest == 10.01


def test_a_restart_is_confirmed_by_frames_in_a_row_on_the_new_clock() -> None:
    line = DeviceTimeline(0.5, confirm=3)
    assert line.judge("imu", 100.0, 0.0) == "take"
    assert line.judge("imu", 0.0, 0.01) == "off_timeline"
    assert line.judge("pose", 0.0, 0.01) == "off_timeline"
    assert line.judge("imu", 0.01, 0.02) == "restarted"
    assert line.newest == 0.01 and not line.pending
    assert line.judge("imu", 0.01, 0.02) == "not_newer"  # the new clock's rules from now on
    assert line.judge("pose", 0.0, 0.02) == "not_newer"
    assert line.judge("pose", 0.05, 0.06) == "take"
    assert line.judge("imu", 99.0, 0.06) == "off_timeline"  # the old clock is gone
    assert line.judge("imu", 0.06, 0.07) == "take"


def test_a_status_of_a_device_just_powered_up_confirms_at_once() -> None:
    line = DeviceTimeline(0.5, confirm=10)
    assert line.judge("imu", 100.0, 0.0) == "take"
    assert line.judge("status", 0.0, 0.01, fresh=False) == "off_timeline"
    assert line.judge("status", 0.01, 0.02, fresh=True) == "restarted"
    # On the current clock a fresh STATUS is just a STATUS (the host has not spoken yet).
    assert line.judge("status", 0.02, 0.03, fresh=True) == "take"


def test_one_replayed_power_up_status_alone_is_no_restart() -> None:
    line = DeviceTimeline(0.5, confirm=10)
    assert line.judge("imu", 100.0, 0.0) == "take"
    # A STATUS from an earlier power-up (a replay, a backlog): it starts a candidate only.
    assert line.judge("status", 0.01, 0.005, fresh=True) == "off_timeline"
    assert line.pending
    assert line.judge("imu", 100.01, 0.01) == "take"  # the device's clock goes on: no restart
    assert not line.pending and line.newest == 100.01


def test_a_power_up_status_confirms_with_the_frame_that_follows_it() -> None:
    line = DeviceTimeline(0.5, confirm=10)
    assert line.judge("imu", 100.0, 0.0) == "take"
    assert line.judge("status", 0.01, 0.02, fresh=True) == "off_timeline"
    assert line.judge("imu", 0.02, 0.03) == "restarted"  # the second frame of its clock


def test_a_candidate_frame_out_of_order_starts_afresh() -> None:
    line = DeviceTimeline(0.5, confirm=3)
    line.judge("imu", 100.0, 0.0)
    assert line.judge("imu", 5.0, 0.0) == "off_timeline"
    assert line.judge("imu", 5.0, 0.0) == "off_timeline"  # not newer on the candidate: anew
    assert line.judge("imu", 5.01, 0.01) == "off_timeline"
    assert line.judge("imu", 5.02, 0.02) == "restarted"


def test_bad_parameters() -> None:
    with pytest.raises(ValueError, match="tolerance"):
        DeviceTimeline(0.0)
    with pytest.raises(ValueError, match="confirm"):
        DeviceTimeline(0.5, confirm=0)

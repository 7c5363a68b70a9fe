"""The stale-pose safe hold (federation/core/linkwatch.py), on own-clock times."""

from __future__ import annotations

import pytest

from federation.core.linkwatch import (
    MAX_STALE,
    LinkWatch,
    SilenceWatch,
    loss_upper_bound,
    stale_threshold,
)

STALE = 0.125  # s (a binary fraction: the boundary test is exact)


def test_nothing_is_stale_before_the_first_pose() -> None:
    watch = LinkWatch(STALE)
    assert watch.update(100.0, pose_at=None, synced_at=None) is None
    assert not watch.holding


def test_a_pose_older_than_stale_after_holds_once() -> None:
    watch = LinkWatch(STALE)
    assert watch.update(10.125, pose_at=10.0, synced_at=9.9) is None  # exactly stale_after
    assert watch.update(10.13, pose_at=10.0, synced_at=9.9) == "stale_hold"
    assert watch.holding and watch.since == 10.13
    assert watch.update(11.0, pose_at=10.0, synced_at=9.9) is None  # held already


def test_a_threshold_given_judges_in_place_of_the_watchs_own() -> None:
    """Agents sharing one measured link each keep a hold of their own, judged by the
    shared watch's threshold."""
    watch = LinkWatch(STALE)
    assert watch.update(10.2, pose_at=10.0, synced_at=9.9, threshold=0.25) is None
    assert not watch.holding
    assert watch.update(10.26, pose_at=10.0, synced_at=9.9, threshold=0.25) == "stale_hold"
    assert watch.threshold == STALE  # its own measurement is untouched


def test_poses_again_without_a_sync_since_keep_holding() -> None:
    watch = LinkWatch(STALE)
    watch.update(10.5, pose_at=10.0, synced_at=9.9)
    assert watch.update(11.0, pose_at=10.95, synced_at=9.9) is None  # sync is older
    assert watch.update(11.1, pose_at=11.05, synced_at=10.5) is None  # exactly at the hold
    assert watch.holding


def test_a_sync_since_without_poses_keeps_holding() -> None:
    watch = LinkWatch(STALE)
    watch.update(10.5, pose_at=10.0, synced_at=9.9)
    assert watch.update(11.0, pose_at=10.0, synced_at=10.9) is None
    assert watch.holding


def test_poses_and_a_sync_since_the_hold_resume() -> None:
    watch = LinkWatch(STALE)
    watch.update(10.5, pose_at=10.0, synced_at=9.9)
    assert watch.update(11.0, pose_at=10.95, synced_at=10.6) == "link_resumed"
    assert not watch.holding
    assert watch.update(11.05, pose_at=11.0, synced_at=10.6) is None  # running again


def test_a_second_outage_needs_a_sync_after_the_second_hold() -> None:
    watch = LinkWatch(STALE)
    watch.update(10.5, pose_at=10.0, synced_at=9.9)
    watch.update(11.0, pose_at=10.95, synced_at=10.6)
    assert watch.update(12.0, pose_at=11.0, synced_at=10.6) == "stale_hold"
    assert watch.update(12.5, pose_at=12.45, synced_at=10.6) is None  # the first sync is old
    assert watch.update(12.6, pose_at=12.55, synced_at=12.1) == "link_resumed"


def test_a_sync_never_completed_never_resumes() -> None:
    watch = LinkWatch(STALE)
    watch.update(10.5, pose_at=10.0, synced_at=None)
    assert watch.update(11.0, pose_at=10.95, synced_at=None) is None


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_stale_after_must_be_positive(bad: float) -> None:
    with pytest.raises(ValueError, match="stale_after"):
        LinkWatch(bad)


# -- the measured threshold ------------------------------------------------------------
PERIOD = 0.05  # s, 20 Hz


def _feed(watch: LinkWatch, lost: set[int], n: int = 400, jitter: float = 0.0) -> float:
    """Poses every PERIOD, those numbered in ``lost`` missing, arriving 40 ms after
    their send time (+ alternating ``jitter``); returns the last arrival."""
    arrived = 0.0
    for k in range(n):
        if k in lost:
            continue
        sent = 100.0 + k * PERIOD
        arrived = sent - 60.0 + 0.040 + (jitter if k % 2 else 0.0)
        watch.observe(arrived, sent)
    return arrived


def test_until_measured_the_threshold_is_stale_after() -> None:
    watch = LinkWatch(0.15)
    _feed(watch, set(), n=30)
    assert watch.threshold == 0.15


def test_a_clean_link_tolerates_three_lost_poses_in_a_row() -> None:
    watch = LinkWatch(0.1)
    _feed(watch, set())
    assert watch.period == pytest.approx(PERIOD)
    assert watch.loss == 0.0
    assert watch.threshold == pytest.approx(3 * PERIOD + 0.020)


def test_loss_lengthens_the_threshold_up_to_the_ceiling() -> None:
    one = LinkWatch(0.1)
    _feed(one, set(range(0, 400, 100)))  # 1 %
    five = LinkWatch(0.1)
    _feed(five, set(range(0, 400, 20)))  # 5 %
    twenty = LinkWatch(0.1)
    _feed(twenty, set(range(0, 400, 5)))  # 20 %
    assert one.loss == pytest.approx(0.01, abs=0.003)
    assert five.loss == pytest.approx(0.05, abs=0.005)
    # ln(1e-4)/ln(0.05) = 3.07 -> 4 periods; at 20 % 6 periods, past the 0.25 s ceiling.
    assert five.threshold == pytest.approx(4 * PERIOD + 0.020)
    assert one.threshold < five.threshold < twenty.threshold == MAX_STALE


def test_delay_variation_widens_the_margin() -> None:
    watch = LinkWatch(0.1)
    _feed(watch, set(), jitter=0.010)  # arrival gaps alternate 40 and 60 ms
    assert watch.sigma == pytest.approx(0.010, rel=0.01)
    assert watch.threshold == pytest.approx(3 * PERIOD + 4 * 0.010)


def test_a_cut_is_held_within_the_ceiling_whatever_the_loss() -> None:
    watch = LinkWatch(0.1)
    last = _feed(watch, set(range(0, 400, 3)))  # 33 % loss
    assert watch.update(last + MAX_STALE - 0.001, last, None) is None
    assert watch.update(last + MAX_STALE + 0.001, last, None) == "stale_hold"


def test_repeated_or_reordered_poses_are_not_counted() -> None:
    watch = LinkWatch(0.1)
    watch.observe(1.0, 10.0)
    watch.observe(1.01, 10.0)
    watch.observe(1.02, 9.95)
    assert len(watch._gaps) == 0


def test_stale_threshold_formula() -> None:
    assert stale_threshold(0.05, 0.0, 0.0, floor=0.1) == pytest.approx(0.17)
    assert stale_threshold(0.05, 1.0, 0.0, floor=0.1) == MAX_STALE
    assert stale_threshold(0.01, 0.0, 0.0, floor=0.15) == 0.15  # floor
    assert stale_threshold(0.05, 0.2, 0.0, floor=0.1, ceiling=0.5) == pytest.approx(0.32)


def test_a_pose_older_than_delay_plus_threshold_is_too_old() -> None:
    watch = LinkWatch(0.15)
    assert not watch.too_old(0.04 + 0.15, delay=0.04)
    assert watch.too_old(0.04 + 0.151, delay=0.04)
    assert watch.too_old(0.16, delay=None)
    assert not watch.too_old(5.9, delay=6.0)  # a long path is not stale by itself


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_ceiling_must_be_positive(bad: float) -> None:
    with pytest.raises(ValueError, match="ceiling"):
        LinkWatch(0.15, ceiling=bad)


def test_a_ceiling_below_stale_after_is_raised_to_it() -> None:
    assert LinkWatch(0.5, ceiling=0.25).ceiling == 0.5


# -- silent peers ----------------------------------------------------------------------
def test_a_peer_that_answers_is_never_silent() -> None:
    watch = SilenceWatch(after=2.0)
    for k in range(50):
        watch.requested("kiruna/knatte", k * 0.1)
        watch.answered("kiruna/knatte")
    assert watch.silent_for("kiruna/knatte", 10.0) is None


def test_a_peer_unanswering_for_longer_than_after_is_silent() -> None:
    watch = SilenceWatch(after=2.0)
    for k in range(30):
        watch.requested("kiruna/knatte", 1.0 + k * 0.1)
    assert watch.silent_for("kiruna/knatte", 3.0) is None  # exactly after
    assert watch.silent_for("kiruna/knatte", 3.5) == pytest.approx(2.5)
    watch.answered("kiruna/knatte")
    assert watch.silent_for("kiruna/knatte", 3.6) is None


def test_a_peer_that_left_owes_nothing() -> None:
    watch = SilenceWatch(after=1.0)
    watch.requested("a", 0.0)
    watch.forget("a")
    assert watch.silent_for("a", 10.0) is None
    assert watch.silent_for("never-asked", 10.0) is None


def test_silence_after_must_be_positive() -> None:
    with pytest.raises(ValueError, match="after"):
        SilenceWatch(after=0.0)


def test_loss_upper_bound_is_wilsons() -> None:
    # Values of Wilson's one-sided 95 % bound, computed by hand.
    assert loss_upper_bound(0, 400) == pytest.approx(0.00672, abs=5e-5)
    assert loss_upper_bound(20, 400) == pytest.approx(0.0712, abs=5e-4)
    assert loss_upper_bound(4, 400) < 0.0464 < loss_upper_bound(14, 400)
    assert loss_upper_bound(0, 0) == 1.0 and loss_upper_bound(10, 10) == 1.0


def test_three_poses_lost_in_a_row_do_not_hold_at_5_percent_loss_read_low() -> None:
    """A 5 % link whose 400-pose window happened to read 4 %: three poses lost in a
    row (a 200 ms gap at 20 Hz, as in a testbed run) must not hold."""
    watch = LinkWatch(stale_after=0.15)
    t = 0.0
    for i in range(440):
        t += 0.05
        if i % 25 == 7:  # one in 25 missing: 4 %
            continue
        watch.observe(arrived_at=t + 0.04, sent_at=t)
    assert watch.loss == pytest.approx(0.04, abs=0.005)
    assert watch.loss_bound > 0.05
    assert watch.threshold > 0.2  # four periods, where the measured 4 % gives three
    assert stale_threshold(0.05, watch.loss, 0.0, floor=0.15) < 0.2
    last = t + 0.04
    assert watch.update(last + 0.199, pose_at=last, synced_at=last) is None  # 3 lost: no hold
    assert watch.update(last + MAX_STALE + 0.001, pose_at=last, synced_at=last) == "stale_hold"

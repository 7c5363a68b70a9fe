"""The stale-pose safe hold (federation/core/linkwatch.py), on own-clock times."""

from __future__ import annotations

import pytest

from federation.core.linkwatch import LinkWatch

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

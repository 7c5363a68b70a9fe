"""Contested peers (federation/core/contest.py): two sources speaking for one agent."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core.contest import Channel, ContestWatch, Outcome, in_order

LEADER, EVIL = "a1" * 16, "e7" * 16  # session ids as Zenoh prints them


def test_one_source_is_never_contested() -> None:
    watch = ContestWatch(window=2.0, quiet=5.0)
    for i in range(100):
        assert watch.observe("kiruna/knatte", "pose", LEADER, i * 0.05) == "ok"
        assert watch.observe("kiruna/knatte", "sync", LEADER, i * 0.05) == "ok"
    assert watch.contested(5.0) == {} and watch.contests == 0


def test_a_second_replier_contests_the_peer_and_says_why() -> None:
    watch = ContestWatch(window=2.0, quiet=5.0)
    assert watch.observe("kiruna/knatte", "sync", LEADER, 10.0) == "ok"
    assert watch.observe("kiruna/knatte", "sync", EVIL, 10.001) == "contested"
    assert watch.contests == 1
    reason = watch.reason("kiruna/knatte", 10.002)
    assert reason is not None and "sync replies from 2 sources" in reason
    assert LEADER[:8] in reason and EVIL[:8] in reason
    # Everything from it is held, the genuine source's included: it cannot be told apart.
    assert watch.observe("kiruna/knatte", "sync", LEADER, 10.1) == "held"
    assert watch.observe("kiruna/knatte", "pose", LEADER, 10.1) == "held"
    assert watch.contests == 1  # one contest, however many samples
    assert watch.contested(10.2) == {"kiruna/knatte": reason}
    # Other peers are unaffected.
    assert watch.observe("rome/pinocchio", "pose", EVIL, 10.2) == "ok"


def test_a_pose_without_source_beside_one_with_is_two_sources() -> None:
    watch = ContestWatch()
    assert watch.observe("kiruna/knatte", "pose", LEADER, 1.0) == "ok"
    assert watch.observe("kiruna/knatte", "pose", None, 1.5) == "contested"
    assert "no source id" in (watch.reason("kiruna/knatte", 1.5) or "")


def test_pose_and_sync_are_judged_separately() -> None:
    # A third party's raw-Zenoh publisher carries no source id; its replies name a replier.
    watch = ContestWatch()
    for i in range(10):
        assert watch.observe("lab3/ghost", "pose", None, i * 0.1) == "ok"
        assert watch.observe("lab3/ghost", "sync", LEADER, i * 0.1) == "ok"


def test_sources_further_apart_than_the_window_do_not_contest() -> None:
    watch = ContestWatch(window=2.0, quiet=5.0)
    assert watch.observe("kiruna/knatte", "pose", LEADER, 0.0) == "ok"
    assert watch.observe("kiruna/knatte", "pose", EVIL, 2.5) == "ok"  # LEADER last heard 2.5 s ago
    assert watch.observe("kiruna/knatte", "pose", EVIL, 2.6) == "ok"


def test_a_contest_clears_after_quiet_seconds_without_a_second_source() -> None:
    watch = ContestWatch(window=2.0, quiet=5.0)
    watch.observe("kiruna/knatte", "pose", LEADER, 0.0)
    watch.observe("kiruna/knatte", "pose", EVIL, 0.5)  # the impostor's last sample
    t = 0.5
    while t < 4.5:  # the genuine source goes on; the impostor is still within the window
        t += 0.05
        outcome = watch.observe("kiruna/knatte", "pose", LEADER, t)
        if t <= 2.5:
            assert outcome == "held"
    # Last conflict at 2.5 (EVIL at 0.5 fell out of the window after 2.5): quiet until 7.5.
    assert watch.reason("kiruna/knatte", 7.49) is not None
    assert watch.reason("kiruna/knatte", 7.5) is None
    assert watch.observe("kiruna/knatte", "pose", LEADER, 7.55) == "ok"
    # The impostor back: contested again, counted again.
    assert watch.observe("kiruna/knatte", "pose", EVIL, 7.6) == "contested"
    assert watch.contests == 2


def test_forget_starts_a_rejoined_peer_clean() -> None:
    # A restarted agent has a new session id: its liveliness token left and came back.
    watch = ContestWatch()
    watch.observe("kiruna/knatte", "pose", LEADER, 0.0)
    watch.forget("kiruna/knatte")
    assert watch.observe("kiruna/knatte", "pose", EVIL, 0.1) == "ok"


@pytest.mark.parametrize(("window", "quiet"), [(0.0, 5.0), (2.0, -1.0), (float("nan"), 1.0)])
def test_bad_parameters_are_refused(window: float, quiet: float) -> None:
    with pytest.raises(ValueError, match="positive"):
        ContestWatch(window, quiet)


class _Reference:
    """The contest rule written out with no shortcut: every observation prunes the
    sources heard too long ago, and two left contest the peer."""

    def __init__(self, window: float, quiet: float):
        self.window, self.quiet = window, quiet
        self.seen: dict[tuple[str, str], dict[str | None, float]] = {}
        self.reason: dict[str, str | None] = {}
        self.conflict_at: dict[str, float] = {}

    def observe(self, peer: str, channel: str, source: str | None, now: float) -> Outcome:
        seen = self.seen.setdefault((peer, channel), {})
        seen[source] = now
        for other in [s for s, t in seen.items() if now - t > self.window]:
            del seen[other]
        if len(seen) > 1:
            self.conflict_at[peer] = now
            if self.reason.get(peer) is None:
                self.reason[peer] = "contested"
                return "contested"
            return "held"
        if self.contested(peer, now):
            return "held"
        return "ok"

    def contested(self, peer: str, now: float) -> bool:
        if self.reason.get(peer) is None:
            return False
        if now - self.conflict_at[peer] >= self.quiet:
            self.reason[peer] = None
            return False
        return True


@given(
    st.lists(
        st.tuples(
            st.sampled_from(["a/x", "b/y"]),
            st.sampled_from(["pose", "sync"]),
            st.sampled_from([LEADER, EVIL, None]),
            st.floats(0.0, 4.0),  # time since the previous observation (s)
        ),
        max_size=80,
    )
)
def test_observe_agrees_with_the_rule_written_out(
    events: list[tuple[str, Channel, str | None, float]],
) -> None:
    """The one-source shortcut (issue 17) changes no outcome."""
    watch, reference = ContestWatch(window=2.0, quiet=5.0), _Reference(2.0, 5.0)
    now = 0.0
    for peer, channel, source, dt in events:
        now += dt
        assert watch.observe(peer, channel, source, now) == reference.observe(
            peer, channel, source, now
        )
        assert (watch.reason(peer, now) is not None) == reference.contested(peer, now)


def test_a_pose_no_newer_from_its_source_is_out_of_order() -> None:
    last: dict[str, tuple[str | None, float]] = {}
    assert in_order(last, "lead", "aaaa", 10.0)
    assert in_order(last, "lead", "aaaa", 10.05)
    assert not in_order(last, "lead", "aaaa", 10.0)  # reordered: older than the last
    assert not in_order(last, "lead", "aaaa", 10.05)  # delivered twice
    assert last["lead"] == ("aaaa", 10.05)  # a dropped one changes nothing
    assert in_order(last, "other", "aaaa", 1.0)  # each peer on its own
    # A restarted sender (a new session) counts time afresh: taken from its return.
    assert in_order(last, "lead", "bbbb", 2.0)
    assert not in_order(last, "lead", "bbbb", 1.9)
    # No source id: ordered by t alone, until the caller forgets the peer.
    assert in_order(last, "legacy", None, 5.0)
    assert not in_order(last, "legacy", None, 4.0)
    del last["legacy"]
    assert in_order(last, "legacy", None, 4.0)


@given(st.lists(st.floats(-1e6, 1e6), max_size=30))
def test_the_poses_taken_from_one_source_only_move_forward(ts: list[float]) -> None:
    last: dict[str, tuple[str | None, float]] = {}
    taken = [t for t in ts if in_order(last, "p", "s", t)]
    assert taken == sorted(set(taken)) and len(taken) == len(set(taken))


def test_a_new_speaker_is_news_once_and_again_after_forget() -> None:
    watch = ContestWatch()
    assert not watch.new_speaker("lead", "aaaa")  # never observed: nothing to say
    assert watch.observe("lead", "pose", "aaaa", 0.0) == "ok"
    assert watch.new_speaker("lead", "aaaa")  # first heard
    assert not watch.new_speaker("lead", "aaaa")
    assert not watch.new_speaker("lead", None)  # no source id: never news
    watch.forget("lead")  # left and rejoined
    assert watch.observe("lead", "pose", "bbbb", 10.0) == "ok"
    assert watch.new_speaker("lead", "bbbb")  # a new session

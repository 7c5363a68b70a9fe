"""Formation guidance (agents/formation.py): the path, the consensus, the slot error."""

from __future__ import annotations

import itertools
import math

import pytest

from agents.formation import CirclePath, FormationGuidance, slot_errors
from federation.core.wire import Pose
from schemas.scenario import FormationConfig

SLOTS = {"a/x": (0.0, 1.0), "b/y": (-1.0, 0.0), "c/z": (1.0, 0.0)}
CONFIG = FormationConfig(slots=SLOTS, radius=0.4, period=50.0, still=5.0, ramp=10.0)


def test_path_is_still_then_ramps_to_the_circle_speed_smoothly() -> None:
    path = CirclePath(CONFIG)
    assert path(0.0) == path(5.0) == (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert math.hypot(path(30.0).vx, path(30.0).vy) == pytest.approx(path.speed)
    assert path.speed == pytest.approx(0.4 * 2 * math.pi / 50)
    # velocity is the derivative of position (and continuous through the ramp's end)
    for t in (7.0, 14.999, 15.0, 40.0):
        h = 1e-5
        a, b = path(t - h), path(t + h)
        assert ((b.x - a.x) / (2 * h), (b.y - a.y) / (2 * h)) == pytest.approx(
            (path(t).vx, path(t).vy), abs=1e-6
        )
        if t != 15.0:  # the acceleration steps where the ramp ends
            assert ((b.vx - a.vx) / (2 * h), (b.vy - a.vy) / (2 * h)) == pytest.approx(
                (path(t).ax, path(t).ay), abs=1e-5
            )


def taken_in(
    g: FormationGuidance, t: float, run_time: float, others: dict[str, tuple[float, Pose]]
) -> None:
    """The others' poses seen ``join_ramp`` seconds before ``t`` (the same ages): taken in
    fully by ``t``."""
    ramp = g.config.join_ramp
    earlier = {agent: (stamp - ramp, pose) for agent, (stamp, pose) in others.items()}
    g.reference(t - ramp, run_time, earlier)


def test_no_track_before_the_run() -> None:
    g = FormationGuidance("a/x", CONFIG)
    assert g.reference(None, None, {}).track is None
    assert g.reference(3.0, None, {}).track is None


def test_alone_it_takes_its_slot_around_the_path() -> None:
    g = FormationGuidance("a/x", CONFIG)
    ref = g.reference(100.0, 30.0, {})
    c = CirclePath(CONFIG)(30.0)
    assert ref.track is not None
    assert (ref.track.x, ref.track.y) == pytest.approx((c.x, c.y + 1.0))
    assert g.used == 0


def test_the_others_pull_the_centre_estimate() -> None:
    g = FormationGuidance("a/x", CONFIG, compensate=False)
    # both others 10 cm to +x of their slots, at the start (path centre at 0, 0)
    others = {"b/y": (10.0, Pose(-0.9, 0.0)), "c/z": (10.0, Pose(1.1, 0.0))}
    taken_in(g, 10.0, 0.0, others)
    ref = g.reference(10.0, 0.0, others)
    assert ref.track is not None
    assert ref.track.x == pytest.approx(0.7 * 0.1)
    assert g.used == 2


def test_stale_poses_are_left_out_and_own_pose_ignored() -> None:
    g = FormationGuidance("a/x", CONFIG)
    others = {"b/y": (8.0, Pose(-0.5, 0.0)), "a/x": (10.0, Pose(5.0, 5.0))}
    ref = g.reference(10.0, 0.0, others)  # b's pose is 2 s old (stale after 1 s)
    assert g.used == 0 and ref.track is not None and ref.track.x == pytest.approx(0.0)


def test_compensation_moves_a_delayed_pose_to_now() -> None:
    moving = {
        "b/y": (9.75, Pose(-1.0, 0.0, 0.0, 0.04, 0.0)),
        "c/z": (9.75, Pose(1.0, 0.0, 0.0, 0.04, 0.0)),
    }
    raw_g = FormationGuidance("a/x", CONFIG, compensate=False)
    comp_g = FormationGuidance("a/x", CONFIG, compensate=True)
    for g in (raw_g, comp_g):
        taken_in(g, 10.0, 0.0, moving)
    raw, comp = raw_g.reference(10.0, 0.0, moving), comp_g.reference(10.0, 0.0, moving)
    assert raw.track is not None and comp.track is not None
    assert comp.track.x - raw.track.x == pytest.approx(0.7 * 0.04 * 0.25)


def test_unknown_member_is_refused() -> None:
    with pytest.raises(ValueError, match="no slot"):
        FormationGuidance("d/w", CONFIG)


def test_slot_errors() -> None:
    c = CirclePath(CONFIG)(30.0)
    errors = slot_errors(CONFIG, 30.0, {"a/x": Pose(c.x + 0.03, c.y + 1.04), "q/q": Pose()})
    assert errors == {"a/x": pytest.approx(0.05)}


def test_a_pose_stamped_far_ahead_is_left_out() -> None:
    # A sender whose reference estimate is 100 s off: its last pose would count for
    # 100 s after it went silent.
    g = FormationGuidance("a/x", CONFIG)
    others = {"b/y": (110.0, Pose(-0.5, 0.0)), "c/z": (10.5, Pose(1.0, 0.0))}
    taken_in(g, 10.0, 0.0, others)
    g.reference(10.0, 0.0, others)
    assert g.used == 1  # c's half a second ahead is within the window; b's is not


def test_a_frozen_run_asks_no_motion() -> None:
    # Rates kept while frozen held each platform about 0.2 m off its frozen point.
    g = FormationGuidance("a/x", CONFIG, compensate=False)
    taken_in(g, 30.0, 20.0, {"b/y": (30.0, Pose(-1.0, 0.0, 0.0, 0.05, 0.0))})
    moving = g.reference(30.0, 20.0, {"b/y": (30.0, Pose(-1.0, 0.0, 0.0, 0.05, 0.0))})
    frozen = g.reference(60.0, 20.0, {"b/y": (60.0, Pose(-1.0, 0.0, 0.0, 0.05, 0.0))}, frozen=True)
    assert moving.track is not None and frozen.track is not None
    assert (moving.track.vx, moving.track.vy) != (0.0, 0.0)
    assert (frozen.track.x, frozen.track.y) == pytest.approx((moving.track.x, moving.track.y))
    assert (frozen.track.vx, frozen.track.vy, frozen.track.ax, frozen.track.ay) == (0, 0, 0, 0)


def test_a_member_joining_or_leaving_moves_the_track_gradually() -> None:
    """b sits 0.25 m off its slot. Its pose appearing, then going silent, had stepped the
    others' track by 0.175 m (0.7 x 0.25) in one control step each way."""
    g = FormationGuidance("a/x", CONFIG, compensate=False)
    off = Pose(-0.75, 0.0)  # b's slot is (-1, 0): 0.25 m to +x of it
    xs, dt = [], 0.01
    for i in range(1200):  # 12 s at 100 Hz: b talks from 1 s to 6 s, then is silent
        t = 10.0 + i * dt
        last_heard = min(t, 16.0)
        others = {"b/y": (last_heard, off)} if t >= 11.0 else {}
        ref = g.reference(t, 0.0, others)
        assert ref.track is not None
        xs.append(ref.track.x)
    steps = [abs(b - a) for a, b in itertools.pairwise(xs)]
    assert max(steps[:600]) <= 0.7 * 0.25 / CONFIG.join_ramp * dt * 1.01  # ramp-in
    assert max(xs) == pytest.approx(0.7 * 0.25)  # fully taken in
    assert xs[-1] == pytest.approx(0.0)  # let go by the time it is stale
    # A new run takes every member in afresh: b, fully taken in, counts from nothing again.
    for t in (30.0, 32.5):
        g.reference(t, 0.0, {"b/y": (t, off)})
    assert g.reference(32.6, 0.0, {"b/y": (32.6, off)}).track.x == pytest.approx(0.175)  # type: ignore[union-attr]
    g.new_run()
    ref = g.reference(32.7, 0.0, {"b/y": (32.7, off)})
    assert ref.track is not None and ref.track.x == pytest.approx(0.0)
    # The fade-out is as gradual: over the last half of stale_after, not at once.
    assert max(steps) <= 0.7 * 0.25 / (CONFIG.stale_after / 2) * dt * 1.01
    assert sum(s > 0 for s in steps[600:]) >= 45  # over about 50 steps, not one


@pytest.mark.parametrize(
    ("settings", "reason"),
    [
        ({"period": 0.5}, "move at 5.03 m/s"),  # 63 m/s^2 on the circle too
        ({"radius": 0.1, "period": 2.5}, "accelerate at 0.632"),
        ({"ramp": 0.05, "radius": 2.0, "period": 30.0}, "in the ramp"),
    ],
)
def test_a_path_no_platform_can_fly_is_refused(settings: dict[str, float], reason: str) -> None:
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=reason):
        FormationConfig(**settings)

"""Docking guidance (agents/docking.py): geometry, the target filter, the phases."""

from __future__ import annotations

import math

import pytest

from agents.docking import DockingGuidance, TargetFilter, TargetGuidance, contact_state
from agents.relative import RelativeMeasurement
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.scenario import DockingConfig, RelativeSensorConfig

DOCK = DockingConfig(target="kiruna/knatte", chaser="rome/pinocchio", hold_time=2.0)
QUIET = RelativeSensorConfig(
    range_noise=0, range_noise_per_m=0, bearing_noise_deg=0, bearing_noise_per_m_deg=0,
    heading_noise_deg=0, dropout=0, rate=20,
)  # fmt: skip


def test_contact_state_axes() -> None:
    target = Pose(1.0, 1.0, math.pi / 2)  # port towards +y
    chaser = Pose(1.02, 1.6, -math.pi / 2 + 0.01, 0.0, -0.01)
    s = contact_state(chaser, target)
    assert s.axial == pytest.approx(0.6)
    assert s.lateral == pytest.approx(-0.02)
    assert s.heading_error == pytest.approx(0.01)
    assert s.closing_speed == pytest.approx(0.01)


def test_target_filter_learns_a_drift() -> None:
    f = TargetFilter()
    own = Pose(2.0, 0.0, math.pi)
    for k in range(200):
        t = k * 0.1
        # target at (0.01 t, 0): seen straight ahead at range 2 - 0.01 t
        f.update(own, RelativeMeasurement(t, 2.0 - 0.01 * t, 0.0, math.pi), QUIET)
    est = f.at(20.0)
    assert est.x == pytest.approx(0.2, abs=1e-3)
    assert est.vx == pytest.approx(0.01, abs=1e-3)


def test_phases_in_kinematic_closed_loop() -> None:
    """A chaser that is exactly where its reference says flies every phase to contact."""
    g = DockingGuidance(DOCK, QUIET)
    target = (0.0, Pose())
    own = Pose(1.3, 0.1, math.pi)
    dt = 0.05
    ref = g.reference(None, None, target, own)
    assert ref.track is None  # before the run: no track
    for k in range(3000):
        t = k * dt
        target = (t, Pose())
        ref = g.reference(t, t, target, own)
        if ref.track is not None:
            own = Pose(ref.track.x, ref.track.y, ref.heading, ref.track.vx, ref.track.vy)
        if g.phase == "contact":
            break
    assert [p for _, p in g.events] == ["approach", "hold", "final", "contact"]
    state = contact_state(own, Pose())
    assert state.axial == pytest.approx(DOCK.contact_distance, abs=0.01)
    assert abs(state.lateral) < 1e-3


def test_backs_off_when_out_of_the_corridor() -> None:
    g = DockingGuidance(DOCK, QUIET)
    g.phase = "final"
    g._carrot = (0.7, 0.0)
    g._last_measurement = 0.0
    own = Pose(0.6, 0.2, math.pi)  # 20 cm off the axis at 10 cm from contact
    g.target.update(
        own, RelativeMeasurement(0.0, math.hypot(0.6, 0.2), math.atan2(0.2, 0.6), math.pi), QUIET
    )
    g.reference(0.05, 0.05, (0.05, Pose()), own)
    assert g.phase == "approach" and g.counters["backoffs_corridor"] == 1


def test_target_holds_rotates_or_drifts_from_its_start() -> None:
    rotating = TargetGuidance(
        DOCK.model_copy(update={"target_rate_deg": 1.0, "target_drift": (0.01, 0.0)})
    )
    assert rotating.reference(None, Pose(0.5, 0.0, 0.2)).track is None
    rotating.reference(0.0, Pose(0.5, 0.0, 0.3))
    ref = rotating.reference(10.0, Pose(9.0, 9.0, 9.0))
    assert ref.heading == pytest.approx(0.2 + math.radians(10.0))
    assert ref.track is not None and (ref.track.x, ref.track.vx) == pytest.approx((0.6, 0.01))


def test_final_speed_must_be_below_the_contact_speed() -> None:
    with pytest.raises(ValueError, match="final_speed"):
        DockingConfig(target="a/b", chaser="c/d", final_speed=0.03)


def _dock(g: DockingGuidance, own: Pose, t0: float = 0.0, dt: float = 0.05) -> tuple[Pose, float]:
    """Fly a chaser that is where its reference says to contact; (own, t) then."""
    t = t0
    for k in range(3000):
        t = t0 + k * dt
        ref = g.reference(t, t - t0, (t, Pose()), own)
        if ref.track is not None:
            own = Pose(ref.track.x, ref.track.y, ref.heading, ref.track.vx, ref.track.vy)
        if g.phase == "contact":
            break
    assert g.phase == "contact"
    return own, t


def test_a_new_run_starts_the_docking_afresh() -> None:
    # Left at contact, a chaser put back at 1.3 m for run 2 was sent straight to the
    # contact point: a step of 0.8 m, full thrust.
    g = DockingGuidance(DOCK, QUIET)
    _, t = _dock(g, Pose(1.3, 0.1, math.pi))
    g.new_run()
    back = Pose(1.3, 0.1, math.pi)
    t += 1.0
    track = None
    for k in range(5):
        ref = g.reference(t + k * 0.05, k * 0.05, (t + k * 0.05, Pose()), back)
        track = ref.track if ref.track is not None else track
    assert g.phase == "approach"
    assert track is not None and math.hypot(track.x - back.x, track.y - back.y) < 0.05


def test_a_frozen_run_holds_the_docking_point_and_phase() -> None:
    g = DockingGuidance(DOCK, QUIET)
    own = Pose(1.3, 0.1, math.pi)
    ref = g.reference(0.0, 0.0, (0.0, Pose()), own)
    for k in range(1, 20):  # approaching
        ref = g.reference(k * 0.05, k * 0.05, (k * 0.05, Pose()), own)
    assert ref.track is not None and g.phase == "approach"
    before, phase = ref.track, g.phase
    for k in range(600):  # 30 s frozen: run time stays at 0.95 s
        t = 1.0 + k * 0.05
        ref = g.reference(t, 0.95, (t, Pose()), own, frozen=True)
    assert g.phase == phase
    assert ref.track is not None
    assert (ref.track.x, ref.track.y) == pytest.approx((before.x, before.y), abs=1e-6)
    assert (ref.track.vx, ref.track.vy) == (0.0, 0.0)


def test_the_target_starts_a_new_run_where_it_is_and_stops_its_drift_when_frozen() -> None:
    target = TargetGuidance(DOCK.model_copy(update={"target_drift": (0.01, 0.0)}))
    target.reference(0.0, Pose(0.0, 0.0, 0.0))
    assert target.reference(100.0, Pose(1.0, 0.0, 0.0)).track is not None
    frozen = target.reference(100.0, Pose(1.0, 0.0, 0.0), frozen=True)
    assert frozen.track is not None and (frozen.track.vx, frozen.rate) == (0.0, 0.0)
    target.new_run()
    ref = target.reference(0.0, Pose(0.3, 0.0, 0.0))  # put back at 0.3 m for run 2
    assert ref.track is not None and ref.track.x == pytest.approx(0.3)


def test_a_silent_target_is_lost_and_not_chased_at_its_old_drift() -> None:
    # The sensor made measurements from a frozen shared pose for ever (never "lost"),
    # and the filter carried a stopped target on at its last drift: the track crept on
    # at 1 cm/s for minutes.
    g = DockingGuidance(DOCK, QUIET)
    own = Pose(1.3, 0.0, math.pi)
    last = (0.0, Pose())
    for k in range(200):  # 10 s of a target drifting at 1 cm/s along +x
        t = k * 0.05
        last = (t, Pose(0.01 * t, 0.0, 0.0, 0.01, 0.0))
        g.reference(t, t, last, own)
    given = g.sensor.counters[Count.RELATIVE_GIVEN]
    tracks = []
    for k in range(1, 2400):  # 120 s: its last pose is all that is shared
        t = 10.0 + k * 0.05
        ref = g.reference(t, t, last, own)
        tracks.append(ref.track)
    assert g.sensor.counters[Count.RELATIVE_GIVEN] <= given + round(QUIET.horizon * QUIET.rate) + 1
    assert g.sensor.counters[Count.RELATIVE_STALE_POSE] > 0
    final = tracks[-1]
    assert final is not None and (final.vx, final.vy) == (0.0, 0.0)
    minute_before = tracks[-1200]
    assert minute_before is not None and abs(final.x - minute_before.x) < 1e-3  # not 0.6 m on

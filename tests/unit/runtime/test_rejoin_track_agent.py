"""A formation member or a docking chaser (re)started while its run is under way
(federation/runtime/agent/rejoining.py), with no Zenoh session, its clock and inputs
driven by hand on simulated time: it rejoins, and the track it flies is captured from
where its platform is onto the scenario's at the preset's speed and acceleration, with
no step, then the scenario's passes through; a chaser inside its final approach, or
with no pose of its target, stays waiting, held, every valve closed. And a follower
whose stale-link hold outlasted its link's lease: it flies on at the run's present time
once poses and a sync exchange return, its reference captured from where its platform
is rather than stepped to where the leader went meanwhile."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from agents.platform import make_platform
from federation.core import keys, wire
from federation.core.angles import wrap_angle
from federation.core.keys import AgentId
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig
from schemas.scenario import DockingConfig, FormationConfig, LabFrame, ScenarioPart

LEAD = AgentId.parse("rome/l")  # the reference clock; the docking's target
ME = "kiruna/f"
DT = 0.01


class _Payload:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Status:
    def __init__(self, status: dict[str, Any]):
        self.payload = _Payload(json.dumps(status).encode())
        self.key_expr = keys.agent_key("default", LEAD, "status")


def _formation(origin: tuple[float, float]) -> ScenarioPart:
    config = FormationConfig(slots={ME: (0.0, 4.0), "lab3/g": (3.5, -2.0)})
    return ScenarioPart(kind="formation", formation=config, frame=LabFrame(origin=origin))


def _docking(origin: tuple[float, float], **docking: Any) -> ScenarioPart:
    config = DockingConfig(target=str(LEAD), chaser=ME, **docking)
    return ScenarioPart(
        kind="docking", docking=config, frame=LabFrame(origin=origin, rotation_deg=180.0)
    )


class _Sink:
    def __init__(self, into: list[str]):
        self.into = into

    def put(self, payload: str, **kwargs: Any) -> None:
        self.into.append(payload)


class Restarted:
    """An agent of a simulated knatte just (re)started in ``scenario``: waiting, held."""

    def __init__(
        self,
        scenario: ScenarioPart | None,
        role: str = "member",
        target: bool = False,
        turning: float = 0.0,
    ):
        self.now = 1000.0
        self.clock = ExecClock(source=lambda: self.now)
        follow = {"follow": str(LEAD)} if role == "follower" else {}
        config = AgentConfig(
            lab="kiruna", name="f", role=role, reference=str(LEAD), sync_window=0.3,
            wait_start=True, scenario=scenario, **follow,
        )  # fmt: skip
        self.agent = AgentRuntime(
            config,
            session=None,  # type: ignore[arg-type]
            clock=self.clock,
            platform=make_platform("knatte", 0, rate=100.0),
        )
        self.statuses: list[str] = []
        self.agent.reporter.publisher = _Sink(self.statuses)
        self.agent.peer_seen(LEAD, True)
        self.target = target  # LEAD shares its pose: at 0, 0, turning at ``turning`` rad/s
        self.turning = turning
        self.cut = False  # LEAD's lab cut off: no pose, no sync

    def sync(self) -> None:
        link = self.agent.peers[LEAD].link
        assert link is not None
        t1 = wire.decode_request(link.client.request(self.clock.now()))
        self.now += 0.005
        link.client.receive(wire.encode_reply(t1, t1 + 0.010, wire.Pose()), self.clock.now())

    def step(self, dt: float = DT) -> None:
        self.now += dt
        if self.target and not self.cut:
            t = self.clock.now() + 0.005  # LEAD's clock
            heading = wrap_angle(1.0 + self.turning * (t - 1000.0))
            pose = wire.Pose(heading=heading, omega=self.turning)
            self.agent.latest_poses[LEAD] = wire.PoseSample(t, pose)
            self.agent.pose_received_at[LEAD] = self.clock.now()
        self.agent.control_step()

    def synced(self) -> None:
        for _ in range(12):
            self.sync()
            self.step(0.09)
        for _ in range(400):  # its platform's estimate settles (fixes agree)
            if self.agent.readiness(self.clock.now()).platform:
                break
            self.step(0.05)
            self.sync()
        ready = self.agent.readiness(self.clock.now())
        assert ready.reference_locked and ready.platform

    def t_sim(self) -> float:
        t = self.agent.sim_time(self.clock.now())
        assert t is not None
        return t

    def run_under_way(self, run_time: float, duration: float = 90.0) -> None:
        t = self.t_sim()
        status = {
            "agent": str(LEAD), "mode": "running", "run_id": "r1", "reference": str(LEAD),
            "t_sim": t, "start_at": t - run_time, "frozen_total": 0.0,
            "duration": duration, "experiment": None, "armed": None,
        }  # fmt: skip
        self.agent.rejoining.on_status(_Status(status))  # type: ignore[arg-type]


def _fly_captured(r: Restarted, seconds: float) -> float:
    """Step ``seconds`` from the rejoin: the track flown never steps beyond the preset's
    limits while captured; returns when it was captured (s after the rejoin)."""
    limits = r.agent.rejoining.track_limits
    prev = None
    captured_after = None
    for k in range(int(seconds / DT)):
        r.step()
        track = r.agent.track
        capturing = r.agent.rejoining.track_capture is not None
        if track is not None and prev is not None and captured_after is None:
            assert math.hypot(track.x - prev.x, track.y - prev.y) <= limits.max_speed * DT + 1e-9
            assert math.hypot(track.vx - prev.vx, track.vy - prev.vy) <= (
                limits.max_accel * DT + 1e-9
            )
            assert math.hypot(track.ax, track.ay) <= limits.max_accel * (1 + 1e-9)
        if not capturing and track is not None and captured_after is None:
            captured_after = k * DT
        prev = track
    assert captured_after is not None, "never captured"
    return captured_after


def test_a_formation_member_rejoins_and_its_track_is_captured_without_a_step() -> None:
    r = Restarted(_formation((0.0, 4.0)))  # its table's origin: its slot at the start
    r.synced()
    r.run_under_way(30.0)
    r.step(0.25)
    state = r.agent.run_state
    assert state.mode == "running" and state.last is not None and state.last.kind == "rejoined"
    assert r.agent.hold is None and not r.agent.platform.held
    capture = r.agent.rejoining.track_capture
    assert capture is not None
    scenario = r.agent.scenario
    assert scenario is not None and scenario.last is not None and scenario.last.track is not None
    slot = scenario.last.track
    pose = r.agent.pose
    off = math.hypot(slot.x - pose.x, slot.y - pose.y)
    assert off > 0.5  # the circle moved on 0.76 m while it was away
    # The first reference flown starts where the platform is, not at the slot.
    assert r.agent.track is not None
    assert math.hypot(r.agent.track.x - pose.x, r.agent.track.y - pose.y) < 0.01
    took = _fly_captured(r, 40.0)
    print(f"formation: {off:.2f} m off its slot, captured {took:.1f} s after the rejoin")
    # Then the scenario's track passes through unchanged, and the platform follows it.
    r.step()
    assert r.agent.track == scenario.last.track
    for _ in range(500):
        r.step()
    truth = r.agent.pose
    track = r.agent.track
    assert track is not None
    assert math.hypot(truth.x - track.x, truth.y - track.y) < 0.05
    assert r.agent.hold is None and not r.agent.platform.held


def test_a_freeze_mid_capture_brings_the_platform_to_the_frozen_point_without_a_step() -> None:
    r = Restarted(_formation((0.0, 4.0)))
    r.synced()
    r.run_under_way(30.0)
    r.step(0.25)
    for _ in range(100):
        r.step()
    before = r.agent.track
    assert before is not None and r.agent.rejoining.track_capture is not None
    r.agent.commands.on_control(_control("freeze", at=r.t_sim(), issued_at=r.t_sim()))
    limits = r.agent.rejoining.track_limits
    prev = before
    for _ in range(300):
        r.step()
        track = r.agent.track
        assert track is not None
        assert math.hypot(track.x - prev.x, track.y - prev.y) <= limits.max_speed * DT + 1e-9
        prev = track
    assert r.agent.run_state.mode == "frozen"


def _control(name: str, **fields: Any) -> Any:
    from cohosted import ControlSample

    return ControlSample({"command": name, "seq": 1, "issuer": "op"} | fields)


def test_a_docking_chaser_beyond_its_hold_point_rejoins_and_is_captured() -> None:
    # The docking experiment's chaser: 1.3 m out on the still target's port axis.
    r = Restarted(_docking((1.3, 0.1)), role="follower", target=True)
    r.synced()
    r.run_under_way(20.0, duration=100.0)
    r.step(0.25)
    assert r.agent.run_state.mode == "running", r.agent.rejoining.decision
    assert r.agent.rejoining.track_capture is not None
    took = _fly_captured(r, 30.0)
    print(f"docking chaser: captured {took:.1f} s after the rejoin")
    assert r.agent.hold is None


@pytest.mark.parametrize(
    ("origin", "why"),
    [
        ((0.6, 0.0), "inside the hold point's 0.80 m (its final approach): no rejoin"),
        ((-1.5, 0.0), "keep-out: no rejoin"),
    ],
)
def test_a_docking_chaser_that_may_not_rejoin_stays_waiting_held(
    origin: tuple[float, float], why: str
) -> None:
    r = Restarted(_docking(origin), role="follower", target=True)
    r.synced()
    # 3 s of a run under way (held, the platform drifts on its table's slope: 1 cm/s).
    for k in range(12):
        r.run_under_way(20.0 + 0.25 * k, duration=100.0)
        r.step(0.25)
        assert r.agent.run_state.mode == "waiting" and r.agent.platform.held
        assert not any(r.agent.platform.valves)
    decision = r.agent.rejoining.decision
    assert decision is not None and not decision.join and why in decision.why
    assert r.agent.rejoining.report()["rejoin"] == decision.why


def test_a_docking_chaser_without_its_target_s_pose_stays_waiting() -> None:
    r = Restarted(_docking((1.3, 0.1)), role="member")
    r.synced()
    r.run_under_way(20.0, duration=100.0)
    r.step(0.25)
    decision = r.agent.rejoining.decision
    assert r.agent.run_state.mode == "waiting" and r.agent.platform.held
    assert decision is not None and "no fresh pose of the target rome/l" in decision.why


# -- a hold that outlasted the link's watch ---------------------------------------
def _flying_follower(turning: float) -> Restarted:
    """A follower of LEAD (turning at ``turning`` rad/s) flying a 90 s run started by
    ctl, released."""
    r = Restarted(None, role="follower", target=True, turning=turning)
    r.synced()
    start = r.t_sim() + 0.2
    r.agent.commands.on_control(_control("start", run_id="r1", at=start, duration=90.0))
    released = False
    for k in range(200):  # 2 s flown
        r.step()
        if k % 10 == 0:
            r.sync()
        if not released and r.agent.hold is None:
            released = True  # the start's waiting hold is not one to capture from
            assert r.agent.rejoining.capture is None
    assert released and r.agent.run_state.mode == "running" and r.agent.hold is None
    return r


def _cut(r: Restarted, seconds: float) -> None:
    """LEAD's lab cut off for ``seconds``: no pose, no sync; past its lease (10 s here)
    its liveliness token leaves, and comes back with the link."""
    r.cut = True
    for k in range(int(seconds / 0.05)):
        r.step(0.05)
        if k * 0.05 == 10.0:
            r.agent.peer_seen(LEAD, False)
    r.agent.peer_seen(LEAD, True)
    r.cut = False


def test_a_follower_whose_hold_outlasted_the_lease_flies_on_without_a_step() -> None:
    r = _flying_follower(turning=0.1)
    start_at = r.agent.run_state.start_at
    r.turning = -0.1  # unseen, the leader turns the other way (the held platform coasts on)
    _cut(r, 30.0)
    assert r.agent.run_state.mode == "running" and r.agent.hold == "stale"
    assert r.agent.platform.held and not any(r.agent.platform.valves)
    held_heading = r.agent.pose.heading
    limits = r.agent.rejoining.limits
    released = None
    prev = None
    for k in range(1500):  # poses and sync again; 15 s
        if k % 5 == 0:
            r.sync()  # 5 ms of the clock on
        before = r.now
        r.step()
        dt = r.now - before + (0.005 if k % 5 == 0 else 0.0)
        heading, rate = r.agent.guidance
        if released is None and r.agent.hold is None:
            released = k * DT
            # The first reference flown starts at the platform, not 3 rad on at the leader.
            assert abs(wrap_angle(heading - held_heading)) < 0.05
            assert r.agent.rejoining.capture is not None
        elif released is not None and r.agent.rejoining.capture is not None:
            assert prev is not None
            assert abs(wrap_angle(heading - prev[0])) <= limits.max_rate * dt + 1e-9
            assert abs(rate - prev[1]) <= limits.max_accel * dt + 1e-9
        prev = (heading, rate)
    assert released is not None, "never released"
    print(f"released {released:.2f} s after the link came back")
    state = r.agent.run_state
    # The same run on the same clock: its run time is the reference time since its start.
    assert state.mode == "running" and state.run_id == "r1" and state.start_at == start_at
    assert state.run_time(r.t_sim()) == pytest.approx(r.t_sim() - start_at)
    assert r.agent.rejoining.capture is None, "never captured"
    leader = wrap_angle(1.0 - 0.1 * (r.clock.now() - 1000.0))
    assert abs(wrap_angle(r.agent.guidance[0] - leader)) < 0.05  # on the leader's heading


def test_a_run_that_ends_during_a_hold_captures_nothing_after() -> None:
    r = _flying_follower(turning=0.1)
    r.cut = True
    for _ in range(20):
        r.step(0.05)
    assert r.agent.hold == "stale"
    r.agent.commands.on_control(_control("abort"))
    r.cut = False
    for k in range(100):
        r.step()
        if k % 5 == 0:
            r.sync()
    assert r.agent.run_state.mode == "aborted" and r.agent.platform.held
    assert r.agent.rejoining.capture is None

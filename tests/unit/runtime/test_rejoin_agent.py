"""An agent (re)started while its run is under way (federation/runtime/agent/rejoining.py),
with no Zenoh session, its clock and its inputs driven by hand: it learns the run from
the leader's status and joins at the present run time (``auto``), or stays held until
an operator's admit (``operator``, a real platform's default: without the admit no
valve ever opens), or never (``never``)."""

from __future__ import annotations

import json
from typing import Any

import pytest
from cohosted import ControlSample, Payload

from agents.platform import make_platform
from federation.core import keys, wire
from federation.core.angles import wrap_angle
from federation.core.keys import AgentId
from federation.core.preflight import preflight
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig

LEAD = AgentId.parse("rome/l")
ME = "kiruna/f"
SERIAL = {"platform": "serial:/dev/ttyFAKE"}


class _Sink:
    def __init__(self, into: list[str]):
        self.into = into

    def put(self, payload: str, **kwargs: Any) -> None:
        self.into.append(payload)


class _StatusSample:
    def __init__(self, agent: AgentId, status: dict[str, Any]):
        self.payload = Payload(json.dumps(status).encode())
        self.key_expr = keys.agent_key("default", agent, "status")


class Restarted:
    """A follower of LEAD just (re)started: waiting, held. Its platform is a simulated
    knatte whose releases are counted (a serial device's valves open only once released)."""

    def __init__(self, **settings: Any) -> None:
        self.now = 1000.0
        self.clock = ExecClock(source=lambda: self.now)
        config = AgentConfig(
            lab="kiruna", name="f", role="follower", follow=str(LEAD), sync_window=0.3,
            wait_start=True, **settings,
        )  # fmt: skip
        platform = make_platform("knatte", 0, rate=100.0)
        self.releases = 0
        release = platform.release

        def counted() -> None:
            self.releases += 1
            release()

        platform.release = counted  # type: ignore[method-assign]
        self.agent = AgentRuntime(config, session=None, clock=self.clock, platform=platform)  # type: ignore[arg-type]
        self.statuses: list[str] = []
        self.agent.reporter.publisher = _Sink(self.statuses)
        self.agent.peer_seen(LEAD, True)
        self.seq = 0

    def sync(self) -> None:
        link = self.agent.peers[LEAD].link
        assert link is not None
        t1 = wire.decode_request(link.client.request(self.clock.now()))
        self.now += 0.01
        link.client.receive(wire.encode_reply(t1, t1 + 0.010, wire.Pose()), self.clock.now())

    def synced(self) -> None:
        for _ in range(12):
            self.sync()
            self.now += 0.09
        assert self.agent.readiness(self.clock.now()).reference_locked
        for _ in range(200):  # its platform's estimate settles (fixes agree)
            if self.agent.readiness(self.clock.now()).platform:
                break
            self.step(0.05)
            self.sync()
        assert self.agent.readiness(self.clock.now()).platform

    def t_sim(self) -> float:
        t = self.agent.sim_time(self.clock.now())
        assert t is not None
        return t

    def leader_flies(
        self, run_time: float, run_id: str = "r1", t: float | None = None, **extra: Any
    ) -> float:
        """The leader's status now (or at reference time ``t``): run ``run_id`` at
        ``run_time`` s of 20; its start."""
        t = self.t_sim() if t is None else t
        status = {
            "agent": str(LEAD), "mode": "running", "run_id": run_id, "reference": str(LEAD),
            "t_sim": t, "start_at": t - run_time, "frozen_total": 0.0, "duration": 20.0,
            "run_time": run_time, "experiment": None, "armed": None,
        } | extra  # fmt: skip
        self.agent.rejoining.on_status(_StatusSample(LEAD, status))  # type: ignore[arg-type]
        return t - run_time

    def pose(self, omega: float = 0.1) -> None:
        """The leader turning at ``omega`` (rad/s), 1 rad from its start at t = 1000 s."""
        t = self.clock.now() + 0.005  # the leader's clock
        heading = wrap_angle(1.0 + omega * (t - 1000.0))
        self.agent.latest_poses[LEAD] = wire.PoseSample(t, wire.Pose(heading=heading, omega=omega))
        self.agent.pose_received_at[LEAD] = self.clock.now()

    def command(self, name: str, **fields: Any) -> None:
        self.seq += 1
        command = {"command": name, "seq": self.seq, "issuer": "op"} | fields
        self.agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]

    def step(self, dt: float = 0.05) -> None:
        self.now += dt
        self.pose()
        self.agent.control_step()

    def last_status(self) -> dict[str, Any]:
        self.agent.publish_status()
        status: dict[str, Any] = json.loads(self.statuses[-1])
        return status


def test_auto_joins_at_the_present_run_time_and_captures_without_a_step() -> None:
    r = Restarted()
    assert r.agent.rejoining.policy == "auto"
    r.synced()
    r.step()
    start = r.leader_flies(6.0)
    assert r.agent.run_state.mode == "waiting" and r.agent.platform.held
    r.step(0.25)  # the next look
    state = r.agent.run_state
    assert state.mode == "running" and state.run_id == "r1" and state.start_at == start
    assert state.last is not None and state.last.kind == "rejoined"
    assert state.last.run_time == pytest.approx(6.25, abs=0.02)
    assert r.agent.hold is None and not r.agent.platform.held and r.releases == 1
    status = r.last_status()
    assert status["transition"]["event"] == "rejoined" and status["start_at"] == start
    assert status["rejoin"] is None and status["admit_run"] is None
    # The followed heading is over 1 rad away, turning: the reference captures it within
    # the platform's limits.
    limits = r.agent.rejoining.limits
    prev = r.agent.guidance
    for _ in range(1500):
        r.step(0.01)
        heading, rate = r.agent.guidance
        assert abs(wrap_angle(heading - prev[0])) <= limits.max_rate * 0.01 + 2e-3
        assert abs(rate - prev[1]) <= limits.max_accel * 0.01 + 2e-3
        prev = (heading, rate)
    assert r.agent.rejoining.capture is None, "never captured"


def test_not_synchronized_it_waits_held() -> None:
    r = Restarted()
    r.leader_flies(6.0, t=1000.0)  # no reference time here: its freshness cannot be told
    for _ in range(10):
        r.step(0.25)
    assert r.agent.run_state.mode == "waiting" and r.agent.platform.held and r.releases == 0
    assert "not synchronized" in r.last_status()["rejoin"]


def test_a_real_platform_waits_for_an_admit_and_never_opens_a_valve_without_it() -> None:
    r = Restarted(**SERIAL)
    assert r.agent.rejoining.policy == "operator"
    r.synced()
    for k in range(40):  # 10 s of a run under way, announced every step
        r.leader_flies(6.0 + k * 0.25)
        r.step(0.25)
        assert r.agent.platform.held and r.releases == 0 and r.agent.hold == "waiting"
        assert not any(r.agent.platform.valves)
    assert r.agent.run_state.mode == "waiting"
    status = r.last_status()
    assert status["admit_run"] == "r1"
    assert status["rejoin"] == f"waiting for an operator's admit (fedlab ctl admit {ME})"
    row = preflight([ME], {ME: status}, {ME: 0.1})[0]
    assert row.admit_run == "r1" and row.as_json()["admit_run"] == "r1"
    r.command("admit", participants=[ME])
    assert r.agent.command_log[-1].outcome == "applied"
    r.leader_flies(16.5)
    r.step(0.05)
    assert r.agent.run_state.mode == "running" and r.releases == 1
    assert not r.agent.platform.held
    assert r.agent.rejoining.admitted is False  # one admit, one rejoin


def test_an_admit_for_another_agent_admits_nothing() -> None:
    r = Restarted(**SERIAL)
    r.synced()
    r.command("admit", participants=["kiruna/other"])
    r.leader_flies(6.0)
    r.step(0.25)
    assert r.agent.run_state.mode == "waiting" and r.releases == 0
    assert r.agent.command_log[-1].outcome == "ignored"


def test_an_admit_without_agents_is_malformed_and_admits_nothing() -> None:
    r = Restarted(**SERIAL)
    r.synced()
    r.command("admit")
    r.leader_flies(6.0)
    r.step(0.25)
    assert r.agent.run_state.mode == "waiting" and r.releases == 0
    assert r.agent.command_log[-1].outcome == "malformed"


def test_never_refuses_the_admit_and_stays_held() -> None:
    r = Restarted(rejoin="never")
    r.synced()
    r.command("admit", participants=[ME])
    outcome = r.agent.command_log[-1]
    assert outcome.outcome == "ignored" and "rejoin = never" in outcome.detail
    r.leader_flies(6.0)
    for _ in range(8):
        r.step(0.25)
    assert r.agent.run_state.mode == "waiting" and r.releases == 0


def test_an_admit_while_running_is_ignored() -> None:
    r = Restarted()
    r.synced()
    r.step()
    r.leader_flies(6.0)
    r.step(0.25)
    assert r.agent.run_state.mode == "running"
    r.command("admit", participants=[ME])
    outcome = r.agent.command_log[-1]
    assert outcome.outcome == "ignored" and "admit while running" in outcome.detail


def test_an_admit_given_before_a_run_is_forgotten_once_it_leaves_waiting() -> None:
    r = Restarted(**SERIAL)
    r.synced()
    r.command("admit", participants=[ME])
    assert r.agent.rejoining.admitted
    r.command("start", run_id="r0", duration=0.5)
    r.step(0.05)
    assert r.agent.run_state.mode == "running"
    assert not r.agent.rejoining.admitted


def _rejoined() -> Restarted:
    r = Restarted()
    r.synced()
    r.step()
    r.leader_flies(6.0)
    r.step(0.25)
    assert r.agent.run_state.mode == "running" and r.agent.rejoining.capture is not None
    return r


def test_a_freeze_mid_capture_resumes_it_where_it_was_without_a_step() -> None:
    r = _rejoined()
    r.step(0.01)
    heading, rate = r.agent.guidance
    r.command("freeze", at=r.t_sim(), issued_at=r.t_sim())
    for _ in range(50):  # 2.5 s frozen
        r.step(0.05)
    assert r.agent.run_state.mode == "frozen" and r.agent.rejoining.capture is not None
    r.command("resume", at=r.t_sim(), issued_at=r.t_sim())
    r.step(0.01)
    assert r.agent.run_state.mode == "running"
    after, after_rate = r.agent.guidance
    limits = r.agent.rejoining.limits
    # One control step's worth from where it was, not the 2.5 s frozen at once.
    assert abs(wrap_angle(after - heading)) <= limits.max_rate * 0.05
    assert abs(after_rate - rate) <= limits.max_accel * 0.05


def test_a_run_that_ends_mid_capture_drops_it() -> None:
    r = _rejoined()
    r.command("abort")
    r.step()
    assert r.agent.run_state.mode == "aborted" and r.agent.rejoining.capture is None
    assert r.agent.platform.held


def test_never_says_so_while_waiting() -> None:
    r = Restarted(rejoin="never")
    r.step()
    assert r.last_status()["rejoin"] == "rejoin = never"


def test_what_stays_uncapturable_says_why() -> None:
    # A heading reference and a formation's or docking's track have a capture; a
    # plug-in's reference and a drifting or turning docking target's do not.
    from federation.runtime.agent.rejoining import uncapturable
    from schemas.scenario import DockingConfig, ScenarioPart

    assert uncapturable(None) is None
    assert uncapturable(ScenarioPart(kind="attitude-tracking")) is None
    assert uncapturable(ScenarioPart.model_construct(kind="formation")) is None
    plugin = uncapturable(ScenarioPart.model_construct(kind="orbit"), ME)
    assert plugin is not None and "plug-in" in plugin and "no rejoin" in plugin
    still = DockingConfig(target=str(LEAD), chaser=ME)
    drifting = DockingConfig(target=str(LEAD), chaser=ME, target_drift=(0.01, 0.0))
    turning = DockingConfig(target=str(LEAD), chaser=ME, target_rate_deg=1.0)
    for docking in (still, drifting, turning):  # a chaser is judged where it is
        assert uncapturable(ScenarioPart(kind="docking", docking=docking), ME) is None
    assert uncapturable(ScenarioPart(kind="docking", docking=still), str(LEAD)) is None
    for docking in (drifting, turning):
        why = uncapturable(ScenarioPart(kind="docking", docking=docking), str(LEAD))
        assert why is not None and "drifting or turning target" in why

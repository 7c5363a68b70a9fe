"""The leader's role kept by agents (federation/runtime/agent/role.py), with no Zenoh
session, their clocks and inputs driven by hand: a follower follows only the holder
and holds (``role``) when nobody holds, and switches to the stand-in without a step in
its reference; a leader flies only while acknowledged and holds, deposed, until an
operator's handback; a stand-in's twin exists only while it holds the role, and
starts at the leader's last shared pose."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cohosted import ControlSample, Payload

from agents.platform import make_platform
from federation.core import keys, wire
from federation.core.angles import wrap_angle
from federation.core.holds import Hold
from federation.core.keys import AgentId
from federation.core.standin import Terms
from federation.runtime.agent import AgentRuntime
from federation.runtime.agent.twin import Twin
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig

LEAD = AgentId.parse("kiruna/knatte")
TWIN = AgentId.parse("rome/twin")
FOL = AgentId.parse("rome/f")
EXPERIMENT = f"""
name = "demo"
duration = 20
stand_in = {{ agent = "{TWIN}", preset = "knatte", after = 1.5 }}

[[participants]]
agent = "{LEAD}"
role = "leader"

[[participants]]
agent = "{FOL}"
role = "follower"
follow = "{LEAD}"
"""


class _Sink:
    def __init__(self, into: list[str]):
        self.into = into

    def put(self, payload: str, **kwargs: Any) -> None:
        self.into.append(payload)


class _Sample:
    def __init__(self, agent: AgentId, topic: str, payload: bytes):
        self.payload = Payload(payload)
        self.key_expr = keys.agent_key("default", agent, topic)


def claim(agent: AgentId, kind: str, epoch: int, at: float, holding: bool, **extra: Any) -> Any:
    """A role message of ``agent`` as it sends it."""
    data = {
        "agent": str(agent), "kind": kind, "epoch": epoch, "at": at, "holding": holding,
        "until": None, "asking": False, "ack": None, "top": epoch, "follows": None, "why": "",
    } | extra  # fmt: skip
    return _Sample(agent, "role", json.dumps(data).encode())


class Harness:
    """One agent of the experiment (``who``), at host time ``now``."""

    def __init__(self, tmp_path: Path, who: AgentId, **settings: Any) -> None:
        path = tmp_path / "demo.toml"
        path.write_text(EXPERIMENT, encoding="utf-8")
        self.now = 1000.0
        self.clock = ExecClock(source=lambda: self.now)
        platform = None
        if who == TWIN:
            settings |= {"role": "stand-in", "platform": "knatte", "reference": str(LEAD)}
        else:
            platform = make_platform("knatte", 0, rate=100.0)
            settings.setdefault("reference", str(LEAD))
        config = AgentConfig(
            lab=who.lab, name=who.name, experiment=path, sync_window=0.3, wait_start=True,
            **settings,
        )  # fmt: skip
        self.agent = AgentRuntime(config, session=None, clock=self.clock, platform=platform)  # type: ignore[arg-type]
        self.statuses: list[str] = []
        self.agent.reporter.publisher = _Sink(self.statuses)
        self.peers = [p for p in (LEAD, TWIN) if p != who]
        for peer in self.peers:
            self.agent.peer_seen(peer, True)
        self.seq = 0

    def sync(self) -> None:
        for peer in self.peers:
            link = self.agent.peers[peer].link
            if link is None:
                continue
            t1 = wire.decode_request(link.client.request(self.clock.now()))
            link.client.receive(wire.encode_reply(t1, t1 + 0.005, wire.Pose()), t1 + 0.01)

    def synced(self) -> None:
        for _ in range(12):
            self.sync()
            self.now += 0.1
        for _ in range(200):  # its platform's estimate settles (fixes agree)
            if self.agent.platform.has_fix or isinstance(self.agent.platform, Twin):
                break
            self.step(0.05)
        self.step(0.05)

    def t_sim(self) -> float:
        t = self.agent.sim_time(self.clock.now())
        assert t is not None
        return t

    def hear(self, sample: _Sample) -> None:
        self.agent.role.on_role(sample)  # type: ignore[arg-type]

    def announce(self, run_time: float) -> None:
        """The leader's status: run r1 at ``run_time`` s of 20 (what a rejoin reads)."""
        t = self.t_sim()
        status = {
            "agent": str(LEAD), "mode": "running", "run_id": "r1", "reference": str(LEAD),
            "t_sim": t, "start_at": t - run_time, "frozen_total": 0.0, "duration": 20.0,
            "run_time": run_time, "experiment": "demo", "armed": None,
        }  # fmt: skip
        self.agent.rejoining.on_status(_Sample(LEAD, "status", json.dumps(status).encode()))  # type: ignore[arg-type]

    def command(self, name: str, **fields: Any) -> None:
        self.seq += 1
        command = {"command": name, "seq": self.seq, "issuer": "op"} | fields
        self.agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]

    def step(self, dt: float = 0.05) -> None:
        self.now += dt
        self.sync()
        self.agent.control_step()

    def status(self) -> dict[str, Any]:
        self.agent.publish_status()
        status: dict[str, Any] = json.loads(self.statuses[-1])
        return status

    def role_held(self) -> bool:
        return self.agent.safety.holds(Hold.ROLE)


def test_a_follower_follows_only_the_holder_and_holds_when_nobody_holds(tmp_path: Path) -> None:
    f = Harness(tmp_path, FOL, role="follower", follow=str(LEAD))
    assert f.agent.role.kind == "follower" and TWIN in f.agent.peer_table.targets()
    f.synced()
    assert f.role_held() and f.status()["claim"]["why"] == "nobody claims the role"
    assert f.status()["hold"] in ("waiting", "role")
    t = f.t_sim()
    f.hear(claim(LEAD, "leader", 1, t, True, until=t + 0.9, asking=True))
    f.step()
    assert not f.role_held() and f.agent.follow == LEAD
    assert f.status()["claim"]["follows"] == str(LEAD)
    # The leader silent: its claim expires at its until, and the follower holds.
    for _ in range(20):
        f.step()
    assert f.role_held() and f.agent.follow == LEAD
    assert "kiruna/knatte's epoch 1 expired" in f.status()["claim"]["why"]
    # A claim sent under another agent's key is refused: a twin cannot speak for it.
    forged = claim(LEAD, "leader", 5, f.t_sim(), True)
    f.agent.role.on_role(_Sample(TWIN, "role", forged.payload.data))  # type: ignore[arg-type]
    f.step()
    assert f.role_held()
    # The stand-in claims epoch 2: followed, released.
    f.hear(claim(TWIN, "stand-in", 2, f.t_sim(), True))
    f.step()
    assert f.agent.follow == TWIN and not f.role_held()
    # A held claim of a higher epoch than the one followed: nobody (never two).
    t = f.t_sim()
    f.hear(claim(LEAD, "leader", 3, t, True, until=t + 0.9))
    f.hear(claim(TWIN, "stand-in", 2, t, True))
    f.step()
    assert f.agent.follow == LEAD and not f.role_held()  # the highest epoch counts


def test_the_follower_switches_to_the_stand_in_without_a_step(tmp_path: Path) -> None:
    # The maneuver still (the heading filter's input): the poses below turn at constant
    # rates, and the reference is theirs.
    still = {"still": 100.0}
    f = Harness(tmp_path, FOL, role="follower", follow=str(LEAD), maneuver=still)
    f.synced()
    limits = f.agent.role.limits
    t0 = f.t_sim()

    def leader_turns() -> None:
        t = f.t_sim()
        heading = wrap_angle(0.02 + 0.1 * (t - t0))
        f.agent.latest_poses[LEAD] = wire.PoseSample(t, wire.Pose(heading=heading, omega=0.1))
        f.agent.pose_received_at[LEAD] = f.clock.now()
        f.hear(claim(LEAD, "leader", 1, t, True, until=t + 0.9))

    for _ in range(10):
        leader_turns()
        f.step()
    f.announce(3.0)
    for _ in range(500):  # the rejoin's own capture done, at the platform's 100 Hz
        leader_turns()
        f.step(0.01)
    assert f.agent.run_state.mode == "running" and f.agent.hold is None
    assert f.agent.rejoining.capture is None
    prev = f.agent.guidance
    steps: list[tuple[float, float]] = []
    for k in range(1000):  # 10 s: the leader lost at 0.5 s, the twin claims at 2.5 s
        if k < 50:
            leader_turns()
        elif k >= 250:  # the twin, 0.6 rad from the leader's last, turning the other way
            t = f.t_sim()
            pose = wire.Pose(heading=wrap_angle(1.9 - 0.1 * (t - t0)), omega=-0.1)
            f.agent.latest_poses[TWIN] = wire.PoseSample(t, pose)
            f.agent.pose_received_at[TWIN] = f.clock.now()
            f.hear(claim(TWIN, "stand-in", 2, t, True))
        f.step(0.01)
        heading, rate = f.agent.guidance
        steps.append((abs(wrap_angle(heading - prev[0])), abs(rate - prev[1])))
        prev = (heading, rate)
    assert f.agent.follow == TWIN and f.agent.hold is None and f.agent.role.capture is None
    assert max(s[0] for s in steps) <= limits.max_rate * 0.01 + 2e-3
    assert max(s[1] for s in steps[250:]) <= limits.max_accel * 0.01 + 2e-3


def test_a_leader_flies_only_acknowledged_and_holds_deposed_until_a_handback(
    tmp_path: Path,
) -> None:
    lead = Harness(tmp_path, LEAD, role="leader")
    lead.peers = []  # the reference: its time is its own
    lead.step()
    assert lead.role_held() and "not acknowledged" in lead.status()["claim"]["why"]
    assert lead.agent.role.sent is not None and lead.agent.role.sent.asking
    asked = lead.agent.role.sent.at
    lead.hear(
        claim(TWIN, "stand-in", 0, asked, False, ack={"agent": str(LEAD), "epoch": 1, "at": asked})
    )
    lead.step()
    assert not lead.role_held() and lead.status()["claim"]["holding"]
    # No acknowledgement for a lease (and a quarter second): it lapses and holds.
    for _ in range(round((Terms().lease + 0.25) / 0.05)):
        lead.step()
    assert lead.role_held() and "lease lapsed" in lead.status()["claim"]["why"]
    # The stand-in took epoch 2: deposed, held, and it says how it comes back.
    lead.hear(claim(TWIN, "stand-in", 2, lead.t_sim(), True))
    lead.step()
    why = lead.status()["claim"]["why"]
    assert lead.role_held() and why.startswith("deposed") and "ctl handback kiruna/knatte" in why
    for _ in range(10):  # acknowledgements of its old epoch change nothing
        t = lead.t_sim()
        lead.hear(
            claim(TWIN, "stand-in", 2, t, False, ack={"agent": str(LEAD), "epoch": 1, "at": t})
        )
        lead.step()
        assert lead.role_held()
    # A handback to another leader is not its business; its own is applied.
    lead.command("handback", participants=["kiruna/other"])
    assert not lead.agent.command_log or lead.agent.command_log[-1].command != "handback"
    lead.command("handback", participants=[str(LEAD)])
    assert lead.agent.command_log[-1].outcome == "applied"
    lead.step()
    sent = lead.agent.role.sent
    assert sent is not None and sent.epoch == 3 and sent.asking and lead.role_held()
    lead.hear(
        claim(
            TWIN, "stand-in", 2, sent.at, False, ack={"agent": str(LEAD), "epoch": 3, "at": sent.at}
        )
    )
    lead.step()
    assert not lead.role_held()
    # A second handback: nothing to hand back, and it says so.
    lead.command("handback", participants=[str(LEAD)])
    outcome = lead.agent.command_log[-1]
    assert outcome.outcome == "ignored" and "not deposed" in outcome.detail


def test_the_stand_ins_twin_exists_only_while_it_holds_the_role(tmp_path: Path) -> None:
    s = Harness(tmp_path, TWIN)
    twin = s.agent.platform
    assert isinstance(twin, Twin) and s.agent.role.kind == "stand-in"
    s.synced()
    last = wire.Pose(x=0.5, y=-0.2, heading=0.7, vx=0.01, vy=0.0, omega=0.05)

    def leader_asks() -> None:
        t = s.t_sim()
        s.hear(claim(LEAD, "leader", 1, t, True, asking=True, until=t + 0.9))
        s.agent.role.on_leader_pose(_Sample(LEAD, "pose", wire.encode_pose(t, last)))  # type: ignore[arg-type]

    for _ in range(round((Terms().quiet + 0.2) / 0.05)):  # past its quiet period, it acks
        leader_asks()
        s.step()
    status = s.status()
    assert status["claim"]["ack"]["agent"] == str(LEAD) and not status["claim"]["holding"]
    assert status["role"] == "stand-in"
    s.announce(2.0)
    for _ in range(10):
        leader_asks()
        s.step()
    assert s.agent.run_state.mode == "running"
    assert twin.inner is None and not twin.has_fix and not any(twin.valves)
    # The leader silent past after (1.5 s): it claims epoch 2 and its twin starts there.
    for _ in range(20):
        s.step()
        assert twin.inner is None
    for _ in range(20):
        s.step()
    assert s.agent.role.sent is not None and s.agent.role.sent.holding
    assert s.agent.role.sent.epoch == 2 and twin.inner is not None
    assert s.agent.hold is None and not twin.held
    truth = twin.truth
    assert truth is not None and truth.heading == pytest.approx(0.7, abs=0.05)
    # A handback: it releases the role HANDOVER (1 s) on, and its twin is gone.
    s.command("handback", participants=[str(LEAD)])
    assert s.agent.command_log[-1].outcome == "applied"
    s.step()
    assert s.agent.role.sent.until is not None and twin.inner is not None

    def leader_asks_again() -> None:  # handed back, the leader asks for top + 1
        t = s.t_sim()
        s.hear(claim(LEAD, "leader", 3, t, False, asking=True))

    for _ in range(25):
        leader_asks_again()
        s.step()
    sent = s.agent.role.sent
    assert not sent.holding and twin.inner is None and not twin.has_fix
    assert sent.ack is not None and sent.ack.epoch == 3  # the leader's new epoch acknowledged

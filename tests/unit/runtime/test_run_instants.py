"""A freeze and a resume announced ahead, applied by an agent (federation/runtime/agent):
the loop wakes at the instant rather than at its next control tick, the status says the
freeze armed and then the transition applied (its reference instant and run time) at
the step it applies, and the recording's control event carries the same."""

from __future__ import annotations

import json
from typing import Any

import pytest
from cohosted import ControlSample

from federation.core.channels import Channel
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig


class Leader:
    """A leader agent (its own reference: reference time is its clock) on a clock the
    test moves, its statuses and recorded control events kept."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.clock = ExecClock(source=lambda: self.now)
        config = AgentConfig(lab="kiruna", name="l", role="leader", wait_start=True)
        self.agent = AgentRuntime(config, session=None, clock=self.clock)  # type: ignore[arg-type]
        self.statuses: list[dict[str, Any]] = []
        sink = type(
            "Sink", (), {"put": lambda _, line, **k: self.statuses.append(json.loads(line))}
        )
        self.agent.reporter.publisher = sink()
        self.control: list[dict[str, Any]] = []
        record = self.agent.record

        def kept(topic: Channel, message: Any) -> None:
            if topic == Channel.CONTROL and isinstance(message, dict):
                self.control.append(message)
            record(topic, message)

        self.agent.record = kept  # type: ignore[method-assign]
        self.seq = 0

    def command(self, name: str, **fields: Any) -> None:
        self.seq += 1
        command = {"command": name, "seq": self.seq, "issuer": "op"} | fields
        self.agent.commands.on_control(ControlSample(command))  # type: ignore[arg-type]

    def step(self, dt: float = 0.01) -> None:
        self.now += dt
        self.agent.control_step()

    @property
    def t(self) -> float:
        """Reference time now (the leader's own clock)."""
        t_sim = self.agent.sim_time(self.clock.now())
        assert t_sim is not None
        return t_sim


def test_a_freeze_and_a_resume_apply_at_their_instants_and_status_says_so() -> None:
    f = Leader()
    f.step()
    start = f.t + 0.5
    f.command("start", at=start, run_id="r1", duration=60.0, issued_at=f.t)
    for _ in range(60):
        f.step()
    assert f.agent.run_state.mode == "running"
    # A freeze 0.3 s ahead: armed, the loop's next deadline its instant (not a tick).
    freeze_at = f.t + 0.3045
    f.command("freeze", at=freeze_at, issued_at=f.t)
    f.step(0.0)
    armed = f.statuses[-1]
    assert armed["mode"] == "running" and armed["armed"] == {
        "event": "freeze", "at": freeze_at, "run_time": None, "detail": ""
    }  # fmt: skip
    assert f.agent.transition_due() == pytest.approx(f.now + 0.3045, abs=1e-9)
    while f.t < freeze_at:
        f.step()
    frozen = f.statuses[-1]  # published at the step it applied, not a second later
    assert frozen["mode"] == "frozen" and frozen["armed"] is None
    run_time = freeze_at - start
    assert frozen["transition"]["event"] == "frozen"
    assert frozen["transition"]["at"] == freeze_at
    assert frozen["transition"]["run_time"] == pytest.approx(run_time, abs=1e-9)
    assert f.control[-1]["event"] == "frozen" and f.control[-1]["t_sim"] == freeze_at
    assert f.control[-1]["run_time"] == pytest.approx(run_time, abs=1e-9)
    # A resume 0.3 s ahead, the same way.
    resume_at = f.t + 0.3
    f.command("resume", at=resume_at, issued_at=f.t)
    f.step(0.0)
    assert f.statuses[-1]["armed"]["event"] == "resume" and f.agent.run_state.mode == "frozen"
    while f.t < resume_at:
        f.step()
    resumed = f.statuses[-1]
    assert resumed["mode"] == "running" and resumed["transition"]["at"] == resume_at
    assert resumed["transition"]["run_time"] == pytest.approx(run_time, abs=1e-9)
    assert f.control[-1]["event"] == "resumed"
    assert f.agent.transition_due() == float("inf")  # nothing armed


def test_a_late_freeze_is_recorded_and_reported_as_late() -> None:
    f = Leader()
    f.step()
    f.command("start", run_id="r1", duration=60.0, issued_at=f.t)
    for _ in range(10):
        f.step()
    f.command("freeze", at=f.t - 0.2, issued_at=f.t - 0.25)
    f.step()
    said = "late: received 0.200 s after its instant"
    assert f.statuses[-1]["transition"]["detail"] == said
    assert f.control[-1]["event"] == "frozen" and f.control[-1]["detail"] == said

"""An experiment as a file: who takes part, in which role, flying what.

Every lab runs its agent with the same file (``fedlab agent --experiment FILE
--lab LAB --name NAME``) and anyone starts the run with ``fedlab ctl start
--experiment FILE``: no video call.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from federation.core.keys import DEFAULT_FEDERATION, AgentId
from schemas.config import AgentRef, ManeuverConfig, _Model, _name, load_model

__all__ = ["ExperimentConfig", "Participant", "load_experiment"]


class Participant(_Model):
    agent: AgentRef = Field(description="LAB/NAME")
    role: Literal["leader", "follower"]
    platform: str = Field("kinematic", description="pose source (see fedlab agent --platform)")
    follow: AgentRef | None = Field(None, description="LAB/NAME a follower tracks")
    latency_compensation: bool = Field(True, description="dead-reckon the followed pose")


class ExperimentConfig(_Model):
    name: Annotated[str, _name("experiment name")]
    federation: Annotated[str, _name("federation name")] = DEFAULT_FEDERATION
    duration: float = Field(gt=0, description="seconds of run time after the start")
    start_delay: float = Field(
        3.0, gt=0, le=60, description="seconds between the start command and the start"
    )
    maneuver: ManeuverConfig = Field(default_factory=ManeuverConfig)
    participants: list[Participant] = Field(min_length=1)

    @model_validator(mode="after")
    def _consistent(self) -> ExperimentConfig:
        names = [p.agent for p in self.participants]
        if len(set(names)) != len(names):
            raise ValueError("an agent takes part twice")
        leaders = [p.agent for p in self.participants if p.role == "leader"]
        if len(leaders) != 1:
            raise ValueError(f"an experiment has exactly one leader, not {len(leaders)}")
        for p in self.participants:
            if p.role == "follower" and p.follow is None:
                raise ValueError(f"follower {p.agent} needs 'follow'")
            if p.follow is not None and p.follow not in names:
                raise ValueError(f"{p.agent} follows {p.follow}, who does not take part")
        return self

    @property
    def leader(self) -> AgentId:
        return AgentId.parse(next(p.agent for p in self.participants if p.role == "leader"))

    def participant(self, agent: AgentId) -> Participant | None:
        return next((p for p in self.participants if p.agent == str(agent)), None)


def load_experiment(path: str | Path) -> ExperimentConfig:
    return load_model(ExperimentConfig, path)

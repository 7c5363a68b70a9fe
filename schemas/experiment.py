"""An experiment as a file: who takes part, in which role, flying what.

Every lab runs its agent with the same file (``fedlab agent --experiment FILE
--lab LAB --name NAME``) and anyone starts the run with ``fedlab ctl start
--experiment FILE``: no video call.

``kind`` says what is rehearsed (:mod:`schemas.scenario`):

- ``attitude-tracking`` (default): the leader's maneuver, followers track its heading
  (a follower may schedule its gains: ``adaptive_gains = true`` and ``[adaptive]``);
- ``formation``: N >= 3 platforms in N labs keep their ``[formation.slots]`` around a
  virtual centre on a circle, each from the others' shared poses;
- ``docking``: ``[docking]``'s chaser docks with its target in another lab from
  emulated relative measurements (``[relative_sensor]``).

``[frames.LAB]`` places each lab's table in the common frame (default: identity).

``stand_in = { agent = "rome/knatte-twin", preset = "knatte", after = 2.0 }`` names a
stand-in for the leader (:mod:`federation.core.standin`): a simulated twin that takes
the leader's role when the leader is silent for ``after`` s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from federation.core.keys import DEFAULT_FEDERATION, AgentId
from federation.core.standin import Terms
from schemas.config import AgentRef, ManeuverConfig, RejoinPolicy, _Model, _name, load_model
from schemas.platform import DEFAULT_KIND, platform_kind
from schemas.scenario import (
    AdaptiveConfig,
    DockingConfig,
    FormationConfig,
    LabFrame,
    RelativeSensorConfig,
    ScenarioKind,
    ScenarioPart,
)

__all__ = ["ExperimentConfig", "Participant", "StandIn", "load_experiment", "stricter"]


class Participant(_Model):
    agent: AgentRef = Field(description="LAB/NAME")
    role: Literal["leader", "follower", "member"] = Field(
        description="leader: the reference clock (and the maneuver); follower: tracks "
        "'follow'; member: a formation member"
    )
    platform: str = Field("kinematic", description="pose source (see fedlab agent --platform)")
    follow: AgentRef | None = Field(None, description="LAB/NAME a follower tracks")
    latency_compensation: bool = Field(
        True, description="dead-reckon the followed (or shared) poses to the present"
    )
    adaptive_gains: bool = Field(
        False, description="a follower schedules its heading gains from the leader's motion"
    )
    seed: int | None = Field(None, description="seed of the simulated platform's noise")
    rejoin: RejoinPolicy | None = Field(
        None,
        description="whether it joins a run under way when (re)started: auto, operator (after "
        "fedlab ctl admit), never; none: operator for a real platform, auto for a simulated "
        "one (the experiment's rejoin, if stricter, wins)",
    )


ROLE_TERMS = Terms()
"""The role's default terms (:mod:`federation.core.standin`): the defaults below."""
LEASE = ROLE_TERMS.lease
"""s: the role's lease, the least ``after`` may be."""


class StandIn(_Model):
    """A stand-in for the experiment's leader: a simulated twin that any lab hosts."""

    agent: AgentRef = Field(description="LAB/NAME the twin runs under (not a participant)")
    preset: Literal["knatte", "pinocchio"] = Field(
        description="the platform preset the twin flies: the leader's"
    )
    after: float = Field(
        ROLE_TERMS.after,
        ge=LEASE,
        le=60,
        description=f"seconds the leader must be silent before the twin takes its role "
        f"(at least the role's lease, {LEASE} s)",
    )
    skew: float = Field(
        ROLE_TERMS.skew,
        gt=0,
        lt=LEASE / 4,
        description="seconds: the largest error bound of an agent's reference time (its "
        "one-way delay to the reference plus its estimate's bound) with which it may hold, "
        "claim or follow the role; above the slowest such path, under a quarter of the "
        f"{LEASE} s lease",
    )


STRICTNESS: tuple[RejoinPolicy, ...] = ("auto", "operator", "never")
"""Rejoin policies, least strict first."""


def stricter(a: RejoinPolicy, b: RejoinPolicy) -> RejoinPolicy:
    """The stricter of two rejoin policies (never > operator > auto)."""
    return max(a, b, key=STRICTNESS.index)


class ExperimentConfig(_Model):
    name: Annotated[str, _name("experiment name")]
    federation: Annotated[str, _name("federation name")] = DEFAULT_FEDERATION
    duration: float = Field(gt=0, description="seconds of run time after the start")
    start_delay: float = Field(
        3.0,
        ge=1.0,
        le=60,
        description="seconds between the start command and the start (at least 1: ctl hears "
        "every participant confirm, or aborts, before it)",
    )
    maneuver: ManeuverConfig = Field(default_factory=ManeuverConfig)
    kind: ScenarioKind = Field("attitude-tracking", description="what the experiment rehearses")
    frames: dict[str, LabFrame] = Field(
        default_factory=dict, description="LAB -> its table frame in the common frame"
    )
    formation: FormationConfig | None = None
    docking: DockingConfig | None = None
    relative_sensor: RelativeSensorConfig = Field(default_factory=RelativeSensorConfig)
    adaptive: AdaptiveConfig = Field(default_factory=AdaptiveConfig)
    rejoin: RejoinPolicy = Field(
        "auto",
        description="the most a participant may rejoin a run under way: auto, operator (only "
        "after fedlab ctl admit), never; each participant's own (its platform's default: "
        "operator for a real one) applies if stricter",
    )
    stand_in: StandIn | None = Field(
        None, description="a simulated twin that takes the leader's role when it is lost"
    )
    participants: list[Participant] = Field(min_length=1)

    @model_validator(mode="after")
    def _consistent(self) -> ExperimentConfig:
        names = [p.agent for p in self.participants]
        self._check_roles(names)
        self._check_frames()
        self._check_stand_in(names)
        if self.kind == "formation":
            self._check_formation(names)
        elif self.kind == "docking":
            self._check_docking()
        else:
            self._check_attitude_tracking()
        return self

    def rejoin_of(self, part: Participant) -> RejoinPolicy | None:
        """The rejoin policy of ``part``'s agent: its own, bounded by the experiment's;
        None where its platform's default (operator for a real one, auto otherwise) is it."""
        if part.rejoin is not None:
            return stricter(part.rejoin, self.rejoin)
        return None if self.rejoin == "auto" else self.rejoin

    def _check_roles(self, names: list[str]) -> None:
        """Each agent takes part once; one leads; a follower follows one who takes part;
        only a follower schedules its gains."""
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
            if p.adaptive_gains and p.role != "follower":
                raise ValueError(f"{p.agent}: adaptive_gains applies to a follower only")

    def _check_stand_in(self, names: list[str]) -> None:
        """A stand-in takes part under a name of its own, in attitude tracking, for a
        leader that someone follows."""
        stand_in = self.stand_in
        if stand_in is None:
            return
        if stand_in.agent in names:
            raise ValueError(f"stand_in.agent: {stand_in.agent} is a participant already")
        if self.kind != "attitude-tracking":
            raise ValueError(f"stand_in: a {self.kind} experiment has no leader to stand in for")
        leader = str(self.leader)
        if not any(p.follow == leader for p in self.participants):
            raise ValueError(f"stand_in: nobody follows the leader {leader}")

    def _check_frames(self) -> None:
        """A frame is given only for a lab that takes part."""
        labs = {p.agent.split("/")[0] for p in self.participants}
        for lab in self.frames:
            if lab not in labs:
                raise ValueError(f"frames.{lab}: no participant in lab {lab!r}")

    def _check_attitude_tracking(self) -> None:
        members = [p.agent for p in self.participants if p.role == "member"]
        if members:
            raise ValueError(f"attitude-tracking has no members: {', '.join(members)}")

    def _check_formation(self, names: list[str]) -> None:
        f = self.formation
        if f is None:
            raise ValueError("a formation experiment needs a [formation] table")
        if len(names) < 3:
            raise ValueError(f"a formation needs at least 3 platforms, not {len(names)}")
        labs = [n.split("/")[0] for n in names]
        if len(set(labs)) != len(labs):
            raise ValueError("a formation has one platform per lab")
        missing = [n for n in names if n not in f.slots]
        if missing:
            raise ValueError(f"formation.slots: no slot for {', '.join(missing)}")
        extra = [n for n in f.slots if n not in names]
        if extra:
            raise ValueError(f"formation.slots: {', '.join(extra)} do not take part")
        for p in self.participants:
            if p.role == "follower":
                raise ValueError(f"{p.agent}: formation platforms are members (or the leader)")

    def _check_docking(self) -> None:
        d = self.docking
        if d is None:
            raise ValueError("a docking experiment needs a [docking] table")
        target, chaser = self.participant_named(d.target), self.participant_named(d.chaser)
        if target is None or chaser is None:
            raise ValueError("docking.target and docking.chaser must take part")
        if target.role != "leader":
            raise ValueError(f"docking.target {d.target} must be the leader (the reference)")
        if chaser.role != "follower" or chaser.follow != d.target:
            raise ValueError(f"docking.chaser {d.chaser} must be a follower of {d.target}")
        if d.target.split("/")[0] == d.chaser.split("/")[0]:
            raise ValueError("the chaser and the target are in different labs")

    def participant_named(self, agent: str) -> Participant | None:
        return next((p for p in self.participants if p.agent == agent), None)

    def part(self, agent: AgentId) -> ScenarioPart | None:
        """``agent``'s part of the scenario (None for attitude tracking without adaptive
        gains, which needs no scenario guidance)."""
        p = self.participant(agent)
        if p is None:
            return None
        if self.kind == "attitude-tracking" and not p.adaptive_gains:
            return None
        return ScenarioPart(
            kind=self.kind,
            frame=self.frames.get(agent.lab, LabFrame()),
            formation=self.formation,
            docking=self.docking,
            relative_sensor=self.relative_sensor,
            adaptive=self.adaptive if p.adaptive_gains else None,
        )

    @property
    def leader(self) -> AgentId:
        return AgentId.parse(next(p.agent for p in self.participants if p.role == "leader"))

    def participant(self, agent: AgentId) -> Participant | None:
        return next((p for p in self.participants if p.agent == str(agent)), None)

    def follow_preset(self, part: Participant) -> str | None:
        """The preset (name or platform file) the leader flies, if ``part`` follows the
        leader and the leader's platform is a preset (a serial platform's experiment
        platform is its preset): the follower's model of how the leader flies the
        maneuver (:mod:`agents.flown`). None otherwise: a kinematic or plug-in leader,
        or a follower of a follower (it does not fly the maneuver)."""
        followed = self.participant(AgentId.parse(part.follow)) if part.follow else None
        if followed is None or followed.role != "leader":
            return None
        return (
            followed.platform if platform_kind(followed.platform)[0].kind == DEFAULT_KIND else None
        )


def load_experiment(path: str | Path) -> ExperimentConfig:
    return load_model(ExperimentConfig, path)

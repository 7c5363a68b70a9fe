"""Configuration models. Units are in each field's description.

A bad value fails at load with the file, the field and the reason::

    ConfigError: deploy/agents/rome.toml: field 'sync_period': Input should be greater than 0
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, field_validator, model_validator

from federation.core import paper
from federation.core.channels import Channel
from federation.core.endpoints import endpoint_problem
from federation.core.estimators import DEFAULT_ESTIMATOR, EstimatorName
from federation.core.keys import DEFAULT_FEDERATION, AgentId
from federation.core.rejoin import Policy as RejoinPolicy
from schemas import base
from schemas.base import ConfigError as ConfigError
from schemas.base import format_validation_error as format_validation_error
from schemas.base import load_model as load_model
from schemas.base import validate as validate
from schemas.platform import DEFAULT_KIND, load_platform, platform_kind, validate_platform_spec
from schemas.scenario import ScenarioPart

__all__ = [
    "AgentConfig",
    "ConfigError",
    "ManeuverConfig",
    "RejoinPolicy",
    "RouterConfig",
    "ZenohOptions",
    "format_validation_error",
    "load_model",
]


class _Model(base.Model):
    """The base of this module's models (:class:`schemas.base.Model`, which
    schemas.platform builds on too): frozen, unknown fields refused."""


_name = base.name


def _agent_id(value: str) -> str:
    AgentId.parse(value)
    return value


def _endpoint(value: str) -> str:
    problem = endpoint_problem(value)
    if problem is not None:
        raise ValueError(f"invalid endpoint {value!r}: {problem}")
    return value


Name = Annotated[str, _name("name")]
AgentRef = Annotated[str, AfterValidator(_agent_id)]
Endpoint = Annotated[str, AfterValidator(_endpoint)]


class ZenohOptions(_Model):
    """Zenoh's usual connection flags, shared by every command that opens a session."""

    mode: Literal["client", "peer", "router"] | None = Field(None, description="Zenoh session mode")
    connect: list[Endpoint] = Field(default_factory=list, description="endpoints to dial")
    listen: list[Endpoint] = Field(default_factory=list, description="endpoints to listen on")
    config: Path | None = Field(None, description="Zenoh json5 configuration file")
    cfg: list[str] = Field(
        default_factory=list, description="extra settings KEY:VALUE, VALUE as json5"
    )


class ManeuverConfig(_Model):
    """The leader's reference maneuver (paper section 5)."""

    still: float = Field(
        paper.MANEUVER_STILL, ge=0, description="seconds held still after the start"
    )
    duration: float = Field(
        paper.MANEUVER_DURATION,
        ge=1.0,
        description="seconds to rotate out and back (at least 1: a start naming 1e-12 "
        "asked a rate of 1e300)",
    )
    amplitude_deg: float = Field(
        paper.MANEUVER_AMPLITUDE_DEG, ge=-180, le=180, description="rotation, degrees"
    )


class AgentConfig(_Model):
    """One agent of a federation."""

    federation: Annotated[str, _name("federation name")] = DEFAULT_FEDERATION
    lab: Annotated[str, base.LAB_NAME]
    name: Annotated[str, _name("agent name")]
    role: Literal["leader", "follower", "member", "stand-in"] = Field(
        description="leader, follower or member; stand-in: an experiment's stand-in for its "
        "leader (a simulated twin of its preset, from --experiment: stand_in.agent)"
    )
    follow: AgentRef | None = Field(None, description="LAB/NAME of the agent a follower tracks")
    reference: AgentRef | None = Field(
        None,
        description="LAB/NAME whose clock is simulation time; default: the followed agent "
        "for a follower, the agent itself otherwise",
    )
    sync_with: list[AgentRef] = Field(
        default_factory=list,
        description="LAB/NAME of the agents to query for sync every sync_period; empty: the "
        "reference and the followed agent every sync_period (the reference agent itself, or "
        "any with sync_all, also every other agent seen alive every sync_others_period)",
    )
    sync_all: bool = Field(
        False,
        description="sync pairwise with every agent alive every sync_others_period; default: "
        "only the reference and the followed agent, others' poses being placed on reference "
        "time by the stamp they carry (O(N) sync traffic)",
    )
    sync_period: float = Field(0.1, gt=0, le=10, description="seconds between sync requests")
    sync_others_period: float = Field(
        1.0,
        gt=0,
        le=60,
        description="seconds between sync requests to an agent that is neither the reference "
        "nor the followed one (spread over the period; with an empty sync_with)",
    )
    sync_timeout: float = Field(
        0.5, gt=0, le=10, description="seconds before a request is given up"
    )
    sync_window: float = Field(10.0, gt=0, description="seconds of reference time averaged (Eq. 6)")
    estimator: EstimatorName = Field(
        DEFAULT_ESTIMATOR,
        description="clockfilter: offset and drift by delay-weighted regression; "
        "mean or median: the paper's Eq. 6 over the sync window",
    )
    four_timestamps: bool = Field(
        False, description="use the server's send time (reply attachment) as a fourth timestamp"
    )
    pose_rate: float = Field(20.0, gt=0, le=1000, description="pose samples per second (Hz)")
    status_period: float = Field(1.0, gt=0, le=60, description="seconds between status messages")
    clock_offset: float = Field(0.0, allow_inf_nan=False, description="seconds added to the clock")
    clock_drift_ppm: float = Field(
        0.0, gt=-1e5, lt=1e5, allow_inf_nan=False, description="clock rate error (ppm)"
    )
    clock_step: tuple[float, float] | None = Field(
        None, description="rehearse a clock step: (at own clock time s, jump s)"
    )
    stale_after: float = Field(
        0.15, gt=0, le=10, description="seconds without the followed pose before safe hold"
    )
    duration: float | None = Field(None, gt=0, description="seconds to run; none: until stopped")
    status_json: Path | None = Field(None, description="file to append status lines (JSON) to")
    platform: str = Field(
        "kinematic",
        description="pose source: kinematic, a preset (knatte, pinocchio), a platform TOML "
        "file, serial:PORT, or a plug-in's platform kind (KIND or KIND:ARGUMENT)",
    )
    platform_preset: str | None = Field(
        None,
        description="GNC preset of a serial:PORT platform, a preset name (knatte, pinocchio) "
        "or a platform file: the mass, inertia, thrusters, sensors and gains its navigation "
        "and control are built for; none: knatte",
    )
    seed: int = Field(0, description="seed of the simulated platform's noise")
    follow_preset: str | None = Field(
        None,
        description="a follower's model of how the followed platform flies the maneuver: its "
        "preset name (knatte, pinocchio) or platform file, flown by a noise-free twin as the "
        "heading filter's input (from --experiment: the followed participant's platform); "
        "none: the maneuver itself",
    )
    maneuver: ManeuverConfig = Field(default_factory=ManeuverConfig)
    wait_start: bool = Field(
        False,
        description="wait for a start command (fedlab ctl start); else run from reference time 0",
    )
    watch_all: bool = Field(
        False, description="subscribe to every agent's pose, not only the followed one's"
    )
    record: Path | None = Field(None, description="MCAP file to record the run to")
    runs_dir: Path | None = Field(
        None,
        description="record each run into RUNS_DIR/<run-id>/ (MCAP, status lines, manifest) "
        "and serve the finished ones to fedlab collect; set to runs by --experiment unless "
        "record is given",
    )
    record_max_mb: int = Field(
        2048,
        ge=1,
        le=1 << 20,
        description="MiB a run's recording under runs_dir (or the record file) may take, and "
        "at most half the space free (and not taken by this process's other recordings) when "
        "the run is armed (the agent starts): past it, messages are dropped and counted and the "
        "recording is finished marked truncated (a peer publishing far too fast fills no disk)",
    )
    record_min_free_mb: int = Field(
        256,
        ge=0,
        le=1 << 20,
        description="MiB that must be free on runs_dir's filesystem (256: half a day of a "
        "follower's run): with less, preflight fails (ready.recording false, so ctl start "
        "refuses unless --force) and a run armed all the same is recorded with an error "
        "logged; a killed agent's run is recovered only if its copy leaves this much free; "
        "0: not checked",
    )
    experiment: Path | None = Field(
        None, description="the experiment file this agent takes part in (recorded with each run)"
    )
    run_duration: float | None = Field(
        None, gt=0, description="s of run time after which a run is done, when its start gives none"
    )
    record_channels: list[Channel] | None = Field(
        None, description="channels to record (e.g. /pose/sent); none: all"
    )
    latency_compensation: bool = Field(
        True, description="dead-reckon the followed pose to the present synchronized time"
    )
    scenario: ScenarioPart | None = Field(
        None,
        description="this agent's part of a formation, docking or adaptive-gain scenario "
        "(from --experiment); none: attitude tracking as configured above",
    )
    rejoin: RejoinPolicy | None = Field(
        None,
        description="whether this agent, (re)started while its run is under way, joins it: "
        "auto (when synchronized and ready), operator (only after fedlab ctl admit LAB/NAME), "
        "never; none: operator for a real platform (serial:PORT), auto for a simulated one",
    )

    @field_validator("platform")
    @classmethod
    def _platform(cls, value: str) -> str:
        return validate_platform_spec(value)

    @field_validator("platform_preset", "follow_preset")
    @classmethod
    def _platform_preset(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if platform_kind(value)[0].kind != DEFAULT_KIND:  # kinematic, serial:PORT, ...
            raise ValueError(f"{value!r} is not a preset: give a preset name or a platform file")
        load_platform(value)  # a ConfigError (a ValueError) naming the file and the field
        return value

    @model_validator(mode="after")
    def _roles(self) -> AgentConfig:
        me = f"{self.lab}/{self.name}"
        if self.role == "follower" and self.follow is None:
            raise ValueError("a follower needs 'follow' (LAB/NAME of the agent to track)")
        if self.follow == me:
            raise ValueError(f"agent {me} cannot follow itself")
        if self.role == "stand-in" and (
            self.experiment is None or self.reference is None or self.follow is not None
        ):
            raise ValueError(
                "a stand-in takes its part from its experiment (--experiment, stand_in.agent): "
                "its reference is the leader and it follows nobody"
            )
        if self.role == "stand-in" and platform_kind(self.platform)[0].kind != DEFAULT_KIND:
            raise ValueError(
                f"platform {self.platform}: a stand-in is a simulated twin of the leader's "
                "preset (stand_in.preset), never another kind of platform"
            )
        if self.sync_with and self.sync_all:
            raise ValueError(
                "sync_with and sync_all together: sync_with names the agents queried, "
                "sync_all every agent alive; give one (sync_all had been dropped silently)"
            )
        hardware = self.hardware
        if hardware and not self.wait_start:
            raise ValueError(
                f"platform {self.platform}: a real platform flies only runs an operator "
                "starts (fedlab ctl start): set wait_start = true (--wait-start, or run it "
                "with --experiment)"
            )
        if self.platform_preset is not None and not hardware:
            raise ValueError(
                "platform_preset applies to a real platform (serial:PORT) only; a simulated "
                f"platform's preset is its platform ({self.platform!r})"
            )
        return self

    @property
    def agent(self) -> AgentId:
        return AgentId(self.lab, self.name)

    @property
    def rejoin_policy(self) -> RejoinPolicy:
        """:attr:`rejoin`, or its default: ``operator`` for a real platform, ``auto``
        for a simulated one."""
        if self.rejoin is not None:
            return self.rejoin
        return "operator" if self.hardware else "auto"

    @property
    def hardware(self) -> bool:
        """Whether :attr:`platform` is a real platform (``serial:PORT``, or a plug-in kind
        that says so): it flies only runs an operator starts, in a process of its own."""
        return platform_kind(self.platform)[0].hardware


class RouterConfig(_Model):
    """A lab router: the only fedlab process that crosses the lab's firewall."""

    lab: Annotated[str, base.LAB_NAME]
    listen: list[Endpoint] = Field(default_factory=list, description="endpoints to listen on")
    connect: list[Endpoint] = Field(
        default_factory=list, description="other labs' routers to dial (outbound only)"
    )

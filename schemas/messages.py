"""Messages other than the paper's binary packets: the JSON an agent publishes
on ``.../status`` and appends to ``--status-json``."""

from __future__ import annotations

import json
import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from federation.core.holds import Hold
from schemas.config import ManeuverConfig
from schemas.scenario import LabFrame

__all__ = [
    "CHUNK_SIZE",
    "Command",
    "CommandOutcome",
    "FileEntry",
    "Manifest",
    "PeerStatus",
    "Readiness",
    "RunTransition",
    "Status",
    "Workspace",
    "is_abort",
]


class PeerStatus(BaseModel):
    """What one agent knows of the clock of one peer (peer clock minus own clock)."""

    model_config = ConfigDict(extra="allow")

    offset: float | None = Field(
        description="clock offset estimate now, peer minus self, s (Eq. 4, filtered)"
    )
    delay: float | None = Field(description="median one-way delay of recent exchanges, s")
    error_bound: float | None = Field(
        None, description="largest offset error path asymmetry can cause (last exchange), s"
    )
    bound: float | None = Field(
        None, description="half the mean round-trip excess of the samples used, s"
    )
    drift_ppm: float | None = Field(None, description="peer clock rate minus own, ppm")
    last_offset: float | None = Field(None, description="offset of the last exchange, s")
    last_delay: float | None = Field(None, description="delay of the last exchange, s")
    locked: bool = Field(False, description="the sync window has closed; offset held")
    alive: bool = Field(True, description="the peer's liveliness token is present")
    samples: int = Field(description="accepted exchanges")
    sent: int = Field(0, description="requests sent")
    timeouts: int = Field(0, description="requests that got no reply in time")
    rejected: int = Field(description="rejected replies (all reasons)")
    rejected_by_reason: dict[str, int] = Field(default_factory=dict)
    clock_steps: int = Field(0, description="clock steps detected (estimate reset each time)")
    sharing: int = Field(
        1,
        description="agents of this process on this exchange: its figures are theirs too "
        "(agents on one clock share one exchange with a peer)",
    )
    silent: float | None = Field(
        None,
        description="alarm: seconds the peer, alive, has answered no sync request (over 2 s); "
        "none while it answers",
    )


class Workspace(BaseModel):
    """Where an agent's platform may go, for a view to draw: its lab's table frame in the
    common frame (:math:`p_c = R(\\theta) p_t + o`) and the usable area in that table
    frame. Published by an agent that keeps its platform inside an area (formation,
    docking)."""

    model_config = ConfigDict(extra="allow")

    frame: LabFrame = Field(description="the lab's table frame in the common frame")
    area: tuple[float, float, float, float] = Field(
        description="usable area, table frame: x_min, x_max, y_min, y_max, m"
    )

    @model_validator(mode="after")
    def _ordered(self) -> Workspace:
        x_min, x_max, y_min, y_max = self.area
        if not (math.isfinite(x_min + x_max + y_min + y_max) and x_min < x_max and y_min < y_max):
            raise ValueError(f"area {self.area}: not x_min < x_max, y_min < y_max (finite)")
        return self


class Readiness(BaseModel):
    """What ``fedlab ctl start`` checks of an agent before a run (preflight)."""

    model_config = ConfigDict(extra="allow")

    platform: bool = Field(description="platform ready: not in a fault hold, measurements fresh")
    platform_detail: str = Field("", description="why not, when not")
    recording: bool = Field(description="the next run will be recorded")
    recording_to: str | None = Field(None, description="folder of this agent's recordings")
    reference_locked: bool = Field(
        description="the reference clock's estimate is locked (always true on the reference)"
    )
    reference_bound: float | None = Field(
        None, description="error bound of the reference clock's estimate, s (0 on the reference)"
    )


class CommandOutcome(BaseModel):
    """One command an agent received and what it made of it."""

    model_config = ConfigDict(extra="allow")

    command: str
    issuer: str
    seq: int
    outcome: str = Field(
        description="applied, ignored (not in this mode), or why it was dropped: repeat, "
        "stale, seq out of range, seq jumped"
    )
    detail: str = ""


class Status(BaseModel):
    """One status line; published once per status period."""

    model_config = ConfigDict(extra="allow")

    agent: str = Field(description="LAB/NAME")
    federation: str
    role: Literal["leader", "follower", "member", "stand-in"]
    reference: str = Field(description="LAB/NAME whose clock is the simulation time")
    t_exec: float = Field(description="own execution clock, s")
    host_monotonic: float = Field(description="host monotonic clock read with t_exec, s")
    t_sim: float | None = Field(description="simulation (reference) time, Eq. 5, s")
    mode: str = Field(
        "armed", description="run mode: waiting, armed, running, frozen, done, aborted"
    )
    run_time: float | None = Field(None, description="experiment time since the start, s")
    run_id: str | None = Field(None, description="the run started last (ctl start names it)")
    duration: float | None = Field(None, description="run time after which the run is done, s")
    start_at: float | None = Field(
        None,
        description="the run's start instant on reference time, s (with run_id, duration, "
        "frozen_total and experiment: the run's announcement a rejoining agent reads)",
    )
    frozen_total: float = Field(0.0, description="reference time the run spent frozen, s")
    experiment: str | None = Field(None, description="the experiment the run's start named")
    ready: Readiness | None = Field(None, description="what preflight checks of this agent")
    commands: list[CommandOutcome] = Field(
        default_factory=list, description="the last commands received and what became of each"
    )
    platform: str = Field("kinematic", description="pose source")
    follow: str | None = Field(None, description="LAB/NAME of the agent followed")
    hold: Hold | None = Field(
        None,
        description="why every valve is held closed (null: they may open); each hold's "
        "meaning and what lifts it: docs/holds.md (federation.core.holds.RULES)",
    )
    pose_age: float | None = Field(
        None, description="age of the last pose received from the followed agent, s"
    )
    valves_confirmed: bool | None = Field(
        None,
        description="whether the platform's last valve command is known to have reached it "
        "(a serial link: false after a write was cut off, until a write goes through; the "
        "device's heartbeat failsafe covers the line meanwhile); null: a platform with no link",
    )
    pose: list[float] = Field(description="x, y, heading, vx, vy, omega (m, rad, m/s, rad/s)")
    peers: dict[str, PeerStatus] = Field(
        description="LAB/NAME -> what this agent knows of that agent's clock, for every "
        "agent it has sent a sync request to"
    )
    loop: dict[str, float] = Field(
        default_factory=dict,
        description="control loop: rate_hz, ticks, late_p50_ms, late_p99_ms, late_max_ms",
    )
    counters: dict[str, int] = Field(
        default_factory=dict, description="rejected inputs and served requests"
    )
    contested: dict[str, str] = Field(
        default_factory=dict,
        description="LAB/NAME -> why that agent is contested (two sources speak for it): "
        "nothing from it is used; a follower of it holds",
    )
    workspace: Workspace | None = Field(
        None, description="its lab's frame and usable area, when it keeps one (formation, docking)"
    )
    transition: RunTransition | None = Field(
        None,
        description="the run's last transition applied: its reference instant and run time "
        "(every agent of a run applies a start, freeze or resume at the same ones)",
    )
    armed: RunTransition | None = Field(
        None, description="a freeze or resume announced for an instant to come"
    )
    rejoin: str | None = Field(
        None,
        description="while waiting: why it does not join a run under way (its rejoin policy, "
        "no run, not synchronized, an operator's admit awaited...)",
    )
    admit_run: str | None = Field(
        None,
        description="the run under way it joins once an operator admits it (fedlab ctl admit "
        "LAB/NAME); none: it waits for no admit",
    )
    claim: dict[str, Any] | None = Field(
        None,
        description="an experiment with a stand-in: this agent's last role message "
        "(federation.core.standin.Claim: holding, epoch, until, follows, why...); none: "
        "it keeps no role",
    )


class RunTransition(BaseModel):
    """A run's transition on reference time: one applied (a start, freeze, resume, end or
    abort), or a freeze or resume armed for an instant to come."""

    model_config = ConfigDict(extra="allow")

    event: str = Field(
        description="applied: started, frozen, resumed, done, aborted; armed: freeze, resume"
    )
    at: float | None = Field(description="reference time it applies (applied) at, s")
    run_time: float | None = Field(None, description="run time then, s (applied only)")
    detail: str = Field("", description="how late a freeze came, when it did")


class Command(BaseModel):
    """Execution control, published on ``fedlab/<federation>/control`` (JSON).

    ``admit`` lets the agents it names (``participants``) rejoin a run under way when
    their rejoin policy is ``operator`` (:mod:`federation.core.rejoin`); ``handback``
    hands the leader's role back to the leader it names (:mod:`federation.core.standin`:
    its stand-in releases the role, the deposed leader asks again). Neither changes a
    run state.

    Modelled on SpaceFOM's run/freeze/shutdown modes. ``at`` is a reference
    (simulation) time: every agent acts when its own synchronized clock reaches
    it, so a start is simultaneous without a video call. Without ``at`` the
    command takes effect on receipt. ``seq`` counts one issuer's commands (1, 2,
    3...); ordering is per issuer (:mod:`federation.core.commands`) and an abort
    is honoured whatever its seq, so seq is any integer here and judged there.
    """

    model_config = ConfigDict(extra="forbid")

    command: Literal["start", "freeze", "resume", "abort", "reset", "admit", "handback"]
    at: float | None = Field(None, allow_inf_nan=False, description="reference time, s")
    seq: int = Field(description="the issuer's command number, 1, 2, 3...; repeats are ignored")
    issued_at: float | None = Field(
        None, allow_inf_nan=False, description="reference time when the issuer sent it, s"
    )
    issuer: str = Field("ctl", max_length=200, description="who sent it")
    experiment: str | None = Field(None, max_length=200, description="experiment name")
    maneuver: ManeuverConfig | None = Field(None, description="the leader's maneuver for this run")
    run_id: str | None = Field(
        None,
        max_length=200,
        pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$",
        description="the run a start names",
    )
    duration: float | None = Field(
        None, gt=0, allow_inf_nan=False, description="s of run time after which the run is done"
    )
    participants: list[Annotated[str, Field(max_length=200)]] | None = Field(
        None,
        max_length=4096,
        description="LAB/NAME of every agent a start, freeze, resume, reset or admit is for: "
        "an agent not named ignores it (an abort is for every agent); none: every agent (an "
        "admit names its agents; a handback its one leader, which its stand-in also hears)",
    )

    @model_validator(mode="after")
    def _admit_names(self) -> Command:
        if self.command == "admit" and not self.participants:
            raise ValueError("an admit names the agents it admits (participants)")
        if self.command == "handback" and (not self.participants or len(self.participants) != 1):
            raise ValueError("a handback names the one leader it hands the role back to")
        return self

    def not_for(self, agent: str) -> str | None:
        """Why this command is not for ``agent`` (it names the participants, not this
        one), or None; an abort is for every agent."""
        if self.command == "abort" or self.participants is None or agent in self.participants:
            return None
        return f"not a participant of {self.experiment or 'this run'}"


def is_abort(payload: bytes) -> bool:
    """Whether a control payload that did not validate still says ``abort``: an abort
    is honoured even from a newer or damaged issuer, as long as it says so in JSON."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return False
    except RecursionError:
        # Nested too deep to read (``{"command": "abort", "a": [[[...]]]}``): an abort
        # that cannot be read is still honoured, since honouring one only closes valves.
        return b'"abort"' in bytes(payload)
    return isinstance(data, dict) and data.get("command") == "abort"


def validation_reason(error: ValidationError) -> str:
    """Where a message failed to validate and why, in a line: ``field.sub: message``."""
    first = error.errors()[0]
    return f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"


def malformed_outcome(payload: bytes, why: str) -> CommandOutcome | None:
    """What to report of a control payload that did not validate, if it names its
    issuer and seq (a newer ctl's field, a value out of range): ctl then says why the
    agent refused it rather than "command not seen". None if it names neither."""
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(data, dict):
        return None
    issuer, seq, command = data.get("issuer"), data.get("seq"), data.get("command")
    if not isinstance(issuer, str) or not isinstance(seq, int) or isinstance(seq, bool):
        return None
    return CommandOutcome(
        command=command[:20] if isinstance(command, str) else "?",
        issuer=issuer[:200],
        seq=seq,
        outcome="malformed",
        detail=why[:200],
    )


CHUNK_SIZE = 32 << 10
"""Bytes per chunk an agent serves of a recording (``fedlab collect``): a reply fits one
Zenoh batch (64 KiB), which the low-latency transport fedlab uses cannot fragment; a
larger one does not arrive and can drop the link it was sent on."""


class FileEntry(BaseModel):
    """One finished file of a run, as an agent lists it for ``fedlab collect``."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(max_length=200, pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
    size: int = Field(ge=0, description="bytes")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="of the whole file")


class Manifest(BaseModel):
    """An agent's finished files of one run (reply to a ``recordings`` query)."""

    model_config = ConfigDict(extra="forbid")

    agent: str = Field(description="LAB/NAME")
    run_id: str
    files: list[FileEntry]
    chunk_size: int = Field(CHUNK_SIZE, gt=0, le=CHUNK_SIZE)

"""Messages other than the paper's binary packets: the JSON an agent publishes
on ``.../status`` and appends to ``--status-json``."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from schemas.config import ManeuverConfig

__all__ = ["PeerStatus", "Status"]


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


class Status(BaseModel):
    """One status line; published once per status period."""

    model_config = ConfigDict(extra="allow")

    agent: str = Field(description="LAB/NAME")
    federation: str
    role: Literal["leader", "follower", "member"]
    reference: str = Field(description="LAB/NAME whose clock is the simulation time")
    t_exec: float = Field(description="own execution clock, s")
    host_monotonic: float = Field(description="host monotonic clock read with t_exec, s")
    t_sim: float | None = Field(description="simulation (reference) time, Eq. 5, s")
    mode: str = Field("armed", description="run mode: waiting, armed, running, frozen, aborted")
    run_time: float | None = Field(None, description="experiment time since the start, s")
    platform: str = Field("kinematic", description="pose source")
    follow: str | None = Field(None, description="LAB/NAME of the agent followed")
    hold: str | None = Field(
        None, description="why every valve is held closed: stale (link lost) or aborted"
    )
    pose_age: float | None = Field(
        None, description="age of the last pose received from the followed agent, s"
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


class Command(BaseModel):
    """Execution control, published on ``fedlab/<federation>/control`` (JSON).

    Modelled on SpaceFOM's run/freeze/shutdown modes. ``at`` is a reference
    (simulation) time: every agent acts when its own synchronized clock reaches
    it, so a start is simultaneous without a video call. Without ``at`` the
    command takes effect on receipt. ``seq`` makes repeats idempotent.
    """

    model_config = ConfigDict(extra="forbid")

    command: Literal["start", "freeze", "resume", "abort"]
    at: float | None = Field(None, allow_inf_nan=False, description="reference time, s")
    seq: int = Field(ge=0, description="command number; a repeat of a seen seq is ignored")
    issued_at: float | None = Field(
        None, allow_inf_nan=False, description="reference time when the issuer sent it, s"
    )
    issuer: str = Field("ctl", max_length=200, description="who sent it")
    experiment: str | None = Field(None, max_length=200, description="experiment name")
    maneuver: ManeuverConfig | None = Field(None, description="the leader's maneuver for this run")

"""Settings of ``fedlab bridge udp``: the legacy agent's name in the federation, the two
UDP addresses, the periods of the bridge's two sync links, and what it answers of the
legacy agent's requests (the port they may come from, how many a second).

Units are in each field's description. A bad value fails naming the field::

    ConfigError: command line: field 'sync_period': Input should be greater than 0
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from federation.core.estimators import DEFAULT_ESTIMATOR, ESTIMATORS
from federation.core.keys import DEFAULT_FEDERATION, AgentId, validate_name
from federation.core.sync import DEFAULT_WINDOW
from schemas.config import AgentRef, ConfigError

__all__ = [
    "DEFAULT_REQUEST_BURST",
    "DEFAULT_REQUEST_RATE_LIMIT",
    "UdpBridgeConfig",
    "format_address",
    "parse_address",
]


def parse_address(text: str, what: str = "address") -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` for IPv6) as (host, port); ConfigError if malformed.

    ``what`` names the value in the message (a flag, a field).
    """
    host, sep, port_text = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise ConfigError(f"{what} {text!r}: expected HOST:PORT, e.g. 127.0.0.1:9000")
    return host, port


def format_address(address: tuple[str, int]) -> str:
    """(host, port) as ``HOST:PORT``, an IPv6 host in brackets: :func:`parse_address`'s inverse."""
    host, port = address
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _address(text: str) -> str:
    parse_address(text)
    return text


def _estimator(name: str) -> str:
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}: choose one of {', '.join(ESTIMATORS)}")
    return name


# The paper's agents request every 100 ms (docs/paper.md, section 3.2). Five times that
# leaves a margin for jitter; the burst lets one two seconds late catch up. A forged
# request still draws its 64-byte reply, but at most this many a second (3.2 kB/s).
DEFAULT_REQUEST_RATE_LIMIT = 50.0  # requests per second
DEFAULT_REQUEST_BURST = 20  # requests

Address = Annotated[str, AfterValidator(_address)]
Seconds = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class UdpBridgeConfig(BaseModel):
    """What ``fedlab bridge udp`` was asked to do."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    agent: AgentRef = Field(description="LAB/NAME the legacy agent joins the federation as")
    listen: Address = Field(
        description="HOST:PORT of the bridge's UDP socket: the legacy agent's requests arrive "
        "there and the bridge's requests leave from it"
    )
    peer: Address = Field(
        description="HOST:PORT of the legacy agent: where the bridge's requests go"
    )
    federation: Annotated[str, AfterValidator(lambda v: validate_name(v, "federation name"))] = (
        Field(DEFAULT_FEDERATION, description="federation name")
    )
    role: Literal["leader", "follower"] = Field(
        "follower", description="leader: the legacy agent's clock is the reference time"
    )
    follow: AgentRef | None = Field(
        None,
        description="LAB/NAME whose clock and pose the legacy agent receives; none: the "
        "federation's leader, found by its status",
    )
    sync_period: Seconds = Field(
        0.1, description="seconds between requests, on both links (the UDP keepalive too)"
    )
    sync_timeout: Seconds = Field(0.5, description="seconds before a request is given up")
    sync_window: Seconds = Field(
        DEFAULT_WINDOW, description="seconds of exchanges the offset is averaged over (Eq. 6)"
    )
    estimator: Annotated[str, AfterValidator(_estimator)] = Field(
        DEFAULT_ESTIMATOR,
        description="offset estimator of both links: " + ", ".join(ESTIMATORS),
        json_schema_extra={"enum": list(ESTIMATORS)},
    )
    legacy_timeout: Seconds = Field(
        2.0, description="seconds without an accepted reply before the legacy agent is gone"
    )
    stale_after: Seconds = Field(
        0.25,
        description="seconds after which the followed pose is too old to send the legacy "
        "agent (no reply then, as the agents hold)",
    )
    request_port: int | None = Field(
        None,
        ge=1,
        le=65535,
        description="the only UDP port of --peer's host the legacy agent's requests are "
        "taken from; none: any port of that host (the paper's second channel), which "
        "anyone able to forge that host's address can also use",
    )
    reply_port: int | None = Field(
        None,
        ge=1,
        le=65535,
        description="the UDP port of --peer's host the legacy agent's replies come from; "
        "none: --peer's own (where the bridge's requests go: an agent that answers from "
        "the socket they reach)",
    )
    request_rate_limit: float = Field(
        DEFAULT_REQUEST_RATE_LIMIT,
        gt=0,
        description="requests per second of the legacy agent answered at most, on average "
        "(the paper's agents request at 10 Hz); more are dropped without a reply",
    )
    request_burst: int = Field(
        DEFAULT_REQUEST_BURST,
        gt=0,
        description="requests of the legacy agent answered at once before "
        "request_rate_limit applies (a late one catching up)",
    )
    status_period: Seconds = Field(1.0, description="seconds between status messages")
    status_json: Path | None = Field(None, description="file to append status lines (JSON) to")
    duration: float | None = Field(None, gt=0, description="seconds to run; none: until stopped")

    @model_validator(mode="after")
    def _not_itself(self) -> UdpBridgeConfig:
        if self.follow == self.agent:
            raise ValueError(f"{self.agent} cannot follow itself")
        if parse_address(self.peer) == parse_address(self.listen):
            raise ValueError(
                f"peer {self.peer} is the bridge's own listen address: it would answer "
                "itself and publish a legacy agent that does not exist"
            )
        if not self.legacy_timeout > self.sync_period + self.sync_timeout:
            raise ValueError(
                f"legacy_timeout {self.legacy_timeout:g} s must exceed sync_period + "
                f"sync_timeout ({self.sync_period + self.sync_timeout:g} s): the legacy "
                "agent would be lost between two of its replies"
            )
        return self

    @property
    def me(self) -> AgentId:
        """``agent`` parsed."""
        return AgentId.parse(self.agent)

    @property
    def followed(self) -> AgentId | None:
        """``follow`` parsed."""
        return None if self.follow is None else AgentId.parse(self.follow)

    @property
    def listen_address(self) -> tuple[str, int]:
        return parse_address(self.listen)

    @property
    def peer_address(self) -> tuple[str, int]:
        return parse_address(self.peer)

    @property
    def peer_text(self) -> str:
        """The legacy agent's address as logs and status show it."""
        return format_address(self.peer_address)

"""Settings of the link emulator (``fedlab link``): one direction of the path, the
endpoints, and the whole link's options. Units are in each field's description.

A bad value fails naming the field. A message that refers to another field
quotes its name (``'burst_every'``), so that the command line can print the flag
instead (``--burst-every``).

Two unit systems, on purpose: :class:`LinkOptions` holds what a person types (ms,
s, probabilities), :class:`DirectionConfig` what the model uses (s);
:meth:`LinkOptions.direction` converts one into the other.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, Field, ValidationInfo, field_validator

from schemas.base import Model

__all__ = [
    "DEFAULT_BURST_DURATION",
    "DirectionConfig",
    "JitterDist",
    "LinkEndpoint",
    "LinkOptions",
    "LinkProtocol",
    "parse_endpoint",
]

JitterDist = Literal["normal", "exp", "pareto"]
LinkProtocol = Literal["tcp", "udp"]

DEFAULT_BURST_DURATION = 5.0
"""Burst length (s) when bursts are on and no length is given."""


_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]  # finite, >= 0
_Prob = Annotated[float, Field(ge=0, le=1)]


# -- one direction (model units) -------------------------------------------------
class DirectionConfig(Model):
    """One direction of the emulated path, in seconds."""

    delay: _NonNeg = Field(0.0, description="base one-way delay, s")
    jitter: _NonNeg = Field(0.0, description="jitter scale J, s (meaning per jitter_dist)")
    jitter_dist: JitterDist = Field("normal", description="jitter distribution")
    loss: _Prob = Field(0.0, description="loss probability (a stream: retransmitted after rto)")
    rto: _NonNeg = Field(0.2, description="retransmission timeout of a stream, s")
    reorder: _Prob = Field(0.0, description="probability a datagram is held back")
    reorder_extra: _NonNeg = Field(0.010, description="extra delay of a held-back datagram, s")
    burst_every: _NonNeg = Field(0.0, description="seconds between bursts; 0: no bursts")
    burst_duration: _NonNeg = Field(0.0, description="burst length, s")
    burst_extra: _NonNeg = Field(0.0, description="extra delay during a burst, s")
    burst_jitter_factor: _NonNeg = Field(1.0, description="jitter scale multiplier in a burst")

    @field_validator("burst_duration")
    @classmethod
    def _shorter_than_period(cls, value: float, info: ValidationInfo) -> float:
        every = info.data.get("burst_every")
        if every is not None and every > 0 and value >= every:
            raise ValueError(f"burst_duration must be shorter than 'burst_every' ({every} s)")
        return value


# -- endpoints -------------------------------------------------------------------
_HOSTNAME = re.compile(
    r"^[A-Za-z0-9]([A-Za-z0-9-]*[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]*[A-Za-z0-9])?)*$"
)


@dataclass(frozen=True, slots=True)
class LinkEndpoint:
    """``PROTOCOL/HOST:PORT`` as Zenoh writes it; ``protocol`` None when not given."""

    protocol: LinkProtocol | None
    host: str
    port: int

    @property
    def address(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def __str__(self) -> str:
        return f"{self.protocol}/{self.address}" if self.protocol else self.address


def parse_endpoint(text: str) -> LinkEndpoint:
    """Parse ``tcp/127.0.0.1:7447``, ``udp/[::1]:7447`` or ``127.0.0.1:7447``.

    Raises
    ------
    ValueError
        With the reason, for anything else (other protocols, Zenoh's ``#`` or ``?``
        options, missing or out-of-range port, IPv6 without brackets).
    """
    protocol, rest = _split_protocol(text)
    if "#" in rest or "?" in rest:
        raise ValueError(f"{text!r}: endpoint options (# or ?) are not supported, {_EXAMPLE}")
    host, port_text = _split_address(text, rest)
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{text!r}: port must be a number 0-65535, not {port_text!r}")
    return LinkEndpoint(protocol, host, int(port_text))


_EXAMPLE = "expected tcp/HOST:PORT or udp/HOST:PORT, e.g. tcp/127.0.0.1:7447"


def _split_protocol(text: str) -> tuple[LinkProtocol | None, str]:
    """The endpoint ``text``'s protocol (None if it names none) and the rest of it."""
    if "/" not in text:
        return None, text
    proto, _, rest = text.partition("/")
    if proto not in ("tcp", "udp"):
        raise ValueError(f"{text!r}: protocol {proto!r} not supported, {_EXAMPLE}")
    return ("tcp" if proto == "tcp" else "udp"), rest


def _split_address(text: str, rest: str) -> tuple[str, str]:
    """The host and the port's text of ``rest``, the address part of endpoint ``text``:
    ``[IPV6]:PORT``, or ``HOST:PORT`` with a host name or an IPv4 address."""
    if rest.startswith("["):
        host, sep, port_text = rest[1:].partition("]:")
        if not sep:
            raise ValueError(f"{text!r}: {_EXAMPLE}")
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"{text!r}: {host!r} is not an IPv6 address") from None
        return host, port_text
    host, sep, port_text = rest.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{text!r}: {_EXAMPLE}")
    if ":" in host:
        raise ValueError(f"{text!r}: an IPv6 address needs brackets, e.g. tcp/[::1]:7447")
    if not _HOSTNAME.match(host):
        raise ValueError(f"{text!r}: {host!r} is not a host name or address")
    return host, port_text


def _endpoint(text: str) -> str:
    parse_endpoint(text)
    return text


def _dialable(text: str) -> str:
    if parse_endpoint(text).port == 0:
        raise ValueError("port 0 cannot be dialled")
    return text


# -- the whole link (units of the command line) -----------------------------------
class LinkOptions(Model):
    """A link emulator's settings in the units of ``fedlab link``'s flags (ms, s,
    probabilities); the field ``delay_ms`` is the flag ``--delay-ms``.

    Settings without a ``backward_`` twin apply to both directions; those with one
    apply to the backward direction unless the twin is given. ``asymmetry_ms`` is
    added to the backward direction only.
    """

    listen: Annotated[str, AfterValidator(_endpoint)] = Field(
        description="where clients connect, e.g. tcp/127.0.0.1:7450 (port 0: any free port)"
    )
    to: Annotated[str, AfterValidator(_endpoint), AfterValidator(_dialable)] = Field(
        description="where traffic goes, e.g. tcp/127.0.0.1:7447"
    )
    protocol: LinkProtocol | None = Field(
        None, validate_default=True, description="tcp or udp; none: from the endpoints, else tcp"
    )
    delay_ms: _NonNeg = Field(0.0, description="base one-way delay, both directions, ms")
    jitter_ms: _NonNeg = Field(0.0, description="jitter scale, both directions, ms")
    jitter_dist: JitterDist = Field("normal", description="jitter distribution")
    asymmetry_ms: _NonNeg = Field(0.0, description="extra delay of the backward direction, ms")
    loss: _Prob = Field(
        0.0, description="loss probability (udp: dropped; tcp: retransmitted after rto_ms)"
    )
    rto_ms: _NonNeg = Field(200.0, description="tcp retransmission timeout, ms")
    reorder: _Prob = Field(0.0, description="datagram reorder probability (udp only)")
    reorder_extra_ms: _NonNeg = Field(10.0, description="extra delay of a reordered datagram, ms")
    burst_every: _NonNeg = Field(0.0, description="seconds between bursts; 0: none")
    burst_duration: _NonNeg | None = Field(
        None,
        validate_default=True,
        description=f"burst length, s; none: {DEFAULT_BURST_DURATION:g} s when bursts are on",
    )
    burst_extra_ms: _NonNeg | None = Field(None, description="extra delay in a burst, ms (0)")
    burst_jitter_factor: _NonNeg = Field(3.0, description="jitter multiplier in a burst")
    backward_delay_ms: _NonNeg | None = Field(None, description="backward base delay, ms")
    backward_jitter_ms: _NonNeg | None = Field(None, description="backward jitter scale, ms")
    backward_loss: _Prob | None = Field(None, description="backward loss probability")
    seed: int | None = Field(None, ge=0, description="random seed; none: a fresh one")
    duration: float | None = Field(None, gt=0, allow_inf_nan=False, description="run time, s")
    stats_json: Path | None = Field(None, description="counters written here every second")
    max_queue_mib: float = Field(
        64.0, gt=0, allow_inf_nan=False, description="per-direction queue cap, MiB"
    )
    udp_idle: float = Field(
        60.0, gt=0, allow_inf_nan=False, description="udp client forgotten after this idle, s"
    )

    # Cross-field checks sit on the later field, so an error names it (a field
    # validator sees the fields declared before it in info.data).
    @field_validator("protocol")
    @classmethod
    def _one_protocol(cls, value: LinkProtocol | None, info: ValidationInfo) -> LinkProtocol | None:
        if "listen" not in info.data or "to" not in info.data:
            return value  # reported on those fields
        listen, to = info.data["listen"], info.data["to"]
        named = {parse_endpoint(listen).protocol, parse_endpoint(to).protocol, value} - {None}
        if len(named) > 1:
            raise ValueError(
                f"'listen' {listen}, 'to' {to} and 'protocol' {value or '(unset)'} "
                "name different protocols"
            )
        return value

    @field_validator("reorder")
    @classmethod
    def _datagrams_only(cls, value: float, info: ValidationInfo) -> float:
        if value and _protocol(info.data) == "tcp":
            raise ValueError(
                "a TCP stream never reorders bytes; use 'protocol' udp (or udp/ endpoints)"
            )
        return value

    @field_validator("burst_duration", "burst_extra_ms")
    @classmethod
    def _bursts_on(cls, value: float | None, info: ValidationInfo) -> float | None:
        every = info.data.get("burst_every")
        if every is None:
            return value  # reported on burst_every
        if every == 0:
            if value is not None:
                raise ValueError("needs 'burst_every' > 0 (bursts are off)")
        elif info.field_name == "burst_duration":
            length = DEFAULT_BURST_DURATION if value is None else value
            if length >= every:
                default = " (the default)" if value is None else ""
                raise ValueError(
                    f"{length} s{default} must be shorter than 'burst_every' {every} s"
                )
        return value

    @property
    def proto(self) -> LinkProtocol:
        """The protocol relayed: ``protocol``, else the endpoints', else tcp."""
        return _protocol({"listen": self.listen, "to": self.to, "protocol": self.protocol}) or "tcp"

    @property
    def burst_length(self) -> float:
        """Burst length, s (the default when not given)."""
        return DEFAULT_BURST_DURATION if self.burst_duration is None else self.burst_duration

    def direction(self, name: Literal["forward", "backward"]) -> DirectionConfig:
        """The model settings of one direction, in seconds (asymmetry not included)."""
        delay, jitter, loss = self.delay_ms, self.jitter_ms, self.loss
        if name == "backward":
            delay = delay if self.backward_delay_ms is None else self.backward_delay_ms
            jitter = jitter if self.backward_jitter_ms is None else self.backward_jitter_ms
            loss = loss if self.backward_loss is None else self.backward_loss
        return DirectionConfig(
            delay=delay / 1e3,
            jitter=jitter / 1e3,
            jitter_dist=self.jitter_dist,
            loss=loss,
            rto=self.rto_ms / 1e3,
            reorder=self.reorder,
            reorder_extra=self.reorder_extra_ms / 1e3,
            burst_every=self.burst_every,
            burst_duration=self.burst_length if self.burst_every > 0 else 0.0,
            burst_extra=(self.burst_extra_ms or 0.0) / 1e3,
            burst_jitter_factor=self.burst_jitter_factor,
        )


def _protocol(data: dict[str, object]) -> LinkProtocol | None:
    """``protocol`` if set, else the first endpoint's that names one (``None``: neither)."""
    protocol = data.get("protocol")
    if protocol == "tcp" or protocol == "udp":
        return protocol
    for key in ("listen", "to"):
        text = data.get(key)
        if isinstance(text, str):
            named = parse_endpoint(text).protocol
            if named is not None:
                return named
    return None

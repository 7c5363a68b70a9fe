"""``fedlab link``: a link emulator between two lab routers, a userspace stand-in for netem.

Placed between two Zenoh routers (``lab B router -> link -> lab A router``), it
delays, jitters and, for datagrams, drops and reorders traffic the way the
paper's internet path did (NOTES.md: one-way delay ~40 ms, std 5-11 ms, bursts of
larger deviation every ~3 minutes).

Directions
----------
``forward`` carries what the listening side's clients send towards ``--to``;
``backward`` carries the replies. Each direction has its own
:class:`DirectionModel`; ``asymmetry`` is added to the backward direction only.

Asymmetry is the real limit of every offset estimate (Eq. 4 assumes equal trips):
with trips ``d_f`` and ``d_b`` the estimated offset is off by ``(d_f - d_b) / 2``,
and nothing at the application layer can see it. A link with ``asymmetry = A``
lets a test check that the estimator's reported error bound covers ``A / 2``.

Model (pure, no I/O)
--------------------
The one-way delay of a packet sent at ``now`` is

.. math::

    d = d_0 + J X                   \\quad\\text{outside a burst}

    d = d_0 + d_b + f J X           \\quad\\text{inside a burst}

where ``d_0`` is the base delay (plus ``asymmetry`` backwards), ``X`` a fresh
unit jitter draw, ``J`` the jitter scale, ``d_b`` the burst's extra delay and
``f`` its jitter factor. Jitter is never negative: a path is never faster than
its base delay.

========  ====================================================  =========  ==============
dist      ``J X`` with scale ``J``                              mean       std
========  ====================================================  =========  ==============
normal    half-normal ``|N(0, J)|``                             0.798 J    0.603 J
exp       exponential                                           J          J
pareto    Lomax (Pareto II), shape 1.5, scale ``J / 2``         J          infinite
========  ====================================================  =========  ==============

The Pareto tail is uncapped: ``P(J X > k J) = (1 + 2 k)^{-1.5}``, so one draw in
about 3000 exceeds ``100 J``; on a byte stream such a draw stalls the chunks
behind it too, as a retransmission would.

Burst windows are ``[k E, k E + D)`` seconds after the model's ``start`` for
``k = 1, 2, ...`` (``E = burst_every``, ``D = burst_duration``): a run begins quiet.

Datagrams (:meth:`DirectionModel.sample`) are also lost with probability ``loss``
and, with probability ``reorder``, held ``reorder_extra`` seconds longer so the ones
sent after them overtake them. Otherwise a direction delivers datagrams in the
order they came (:func:`datagram_deliver_at`): jitter stretches the gaps between
them but never swaps two, as netem's FIFO queue does. Reordering is thus only
what ``--reorder`` asks for; Zenoh's UDP links do not reorder, and a declaration
overtaken by what it declares is dropped (routers linked through a jittery
reordering relay exchanged almost nothing). Byte streams
(:class:`StreamScheduler`) are never lost or reordered: a chunk is delivered at
``max(now + d, previous delivery)``.

I/O
---
The asyncio layer only moves bytes: per direction a scheduled queue drained by a
timer (``loop.call_at``), with a fast path that writes at once when a chunk is
already due. TCP mode relays each accepted connection to its own connection to
``--to``; UDP mode relays each client address through its own socket.

A direction (per TCP connection; for UDP, all clients together) whose queue holds
more than ``max_queue_mib`` stops reading its source until the queue is half
drained; the destination's write buffer filling up pauses the source likewise.

Nothing is delivered before its time; timers fire late by the loop's wake-up
latency. The loop uses ``select(2)``, whose timeout has microsecond resolution,
where epoll's is whole milliseconds and asyncio rounds it up (measured here:
timers 0.85 ms late at the median with epoll, 0.13 ms with select). ``select``
takes descriptors below 1024 only, hence the cap of 256 connections or clients.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import heapq
import ipaddress
import json
import logging
import math
import os
import random
import re
import secrets
import selectors
import signal
import socket
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)

from schemas.config import ConfigError

__all__ = [
    "PARETO_SHAPE",
    "DirectionConfig",
    "DirectionModel",
    "DirectionStats",
    "LinkEndpoint",
    "LinkModel",
    "LinkOptions",
    "LinkStats",
    "StreamScheduler",
    "datagram_deliver_at",
    "options_from_args",
    "parse_endpoint",
    "register",
    "run_link",
    "serve",
    "stream_deliver_at",
]

log = logging.getLogger("fedlab.link")

JitterDist = Literal["normal", "exp", "pareto"]
LinkProtocol = Literal["tcp", "udp"]

PARETO_SHAPE = 1.5
"""Shape of the Pareto (Lomax) jitter: heavy tail, finite mean, infinite variance."""

_JITTER_MEAN = {"normal": math.sqrt(2.0 / math.pi), "exp": 1.0, "pareto": 1.0}
_EARLY = 1e-6  # a queued item this close to due is sent now rather than re-armed
_MAX_SESSIONS = 256  # TCP connections or UDP clients: select(2) takes fds < 1024
_READ_BATCH = 64  # datagrams read per wake-up, so one side cannot starve the other
_DIAL_TIMEOUT = 10.0


# -- model ---------------------------------------------------------------------
class DirectionConfig(BaseModel):
    """One direction of the emulated path. Times in seconds."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    delay: float = Field(0.0, ge=0, allow_inf_nan=False, description="base one-way delay, s")
    jitter: float = Field(
        0.0, ge=0, allow_inf_nan=False, description="jitter scale J, s (meaning per jitter_dist)"
    )
    jitter_dist: JitterDist = Field("normal", description="jitter distribution")
    loss: float = Field(
        0.0, ge=0, le=1, description="loss probability (a stream: retransmitted after rto)"
    )
    rto: float = Field(
        0.2, ge=0, allow_inf_nan=False, description="retransmission timeout of a stream, s"
    )
    reorder: float = Field(0.0, ge=0, le=1, description="probability a datagram is held back")
    reorder_extra: float = Field(
        0.010, ge=0, allow_inf_nan=False, description="extra delay of a held-back datagram, s"
    )
    burst_every: float = Field(
        0.0, ge=0, allow_inf_nan=False, description="seconds between bursts; 0: no bursts"
    )
    burst_duration: float = Field(0.0, ge=0, allow_inf_nan=False, description="burst length, s")
    burst_extra: float = Field(
        0.0, ge=0, allow_inf_nan=False, description="extra delay during a burst, s"
    )
    burst_jitter_factor: float = Field(
        1.0, ge=0, allow_inf_nan=False, description="jitter scale multiplier during a burst"
    )

    @model_validator(mode="after")
    def _bursts(self) -> DirectionConfig:
        if self.burst_every > 0 and self.burst_duration >= self.burst_every:
            raise ValueError("burst_duration must be shorter than burst_every")
        return self


def _jitter_sampler(dist: JitterDist, rng: random.Random) -> Callable[[float], float]:
    """A function of the scale ``J`` giving one non-negative jitter draw."""
    if dist == "normal":
        gauss = rng.gauss
        return lambda j: abs(gauss(0.0, j))
    if dist == "exp":
        expo = rng.expovariate
        return lambda j: expo(1.0 / j)
    if dist == "pareto":
        pareto = rng.paretovariate
        # Lomax = Pareto I minus 1, scaled by J (a - 1) so that its mean is J.
        scale = PARETO_SHAPE - 1.0
        return lambda j: j * scale * (pareto(PARETO_SHAPE) - 1.0)
    raise ValueError(f"unknown jitter distribution {dist!r}")


class DirectionModel:
    """Delays for one direction of the path; ``now`` is always passed in.

    Parameters
    ----------
    config : DirectionConfig
        The direction's settings.
    rng : random.Random
        Source of randomness, owned by this model (seed it for a reproducible run).
    start : float
        Time origin of the burst windows (same clock as ``now``).
    asymmetry : float
        Seconds added to the base delay (the backward direction's share), >= 0.
    """

    def __init__(
        self,
        config: DirectionConfig,
        rng: random.Random,
        *,
        start: float = 0.0,
        asymmetry: float = 0.0,
    ):
        if not (asymmetry >= 0 and math.isfinite(asymmetry)):
            raise ValueError(f"asymmetry must be finite seconds >= 0, not {asymmetry!r}")
        self.config = config
        self.rng = rng
        self.start = start
        self.asymmetry = asymmetry
        self.base = config.delay + asymmetry
        self.sent = 0
        self.lost = 0
        self.reordered = 0
        self.held = False  # whether the last datagram sampled was held back (reordered)
        self._jitter_draw = _jitter_sampler(config.jitter_dist, rng)
        self._j = config.jitter
        self._burst_j = config.jitter * config.burst_jitter_factor
        self._random = rng.random

    @property
    def mean_delay(self) -> float:
        """Expected delay outside bursts, excluding reordering (s); infinite variance
        aside, this is also the Pareto mean."""
        return self.base + self._j * _JITTER_MEAN[self.config.jitter_dist]

    def in_burst(self, now: float) -> bool:
        """True if ``now`` is inside a burst window ``[k E, k E + D)``, ``k >= 1``."""
        every = self.config.burst_every
        if every <= 0:
            return False
        t = now - self.start
        return t >= every and math.fmod(t, every) < self.config.burst_duration

    def delay(self, now: float) -> float:
        """Delay (s) of a chunk sent at ``now``: base, jitter and bursts; never lost."""
        if self.in_burst(now):
            j = self._burst_j
            extra = self.config.burst_extra
        else:
            j = self._j
            extra = 0.0
        if j > 0:
            extra += self._jitter_draw(j)
        return self.base + extra

    def sample(self, now: float) -> float | None:
        """Delay (s) of a datagram sent at ``now``, or ``None`` if it is lost.

        A held-back (reordered) datagram gets ``reorder_extra`` more, so datagrams
        sent within that time after it arrive first. Counts ``sent``, ``lost`` and
        ``reordered``; ``held`` tells whether this datagram was held back.
        """
        self.sent += 1
        self.held = False
        config = self.config
        if config.loss > 0 and self._random() < config.loss:
            self.lost += 1
            return None
        d = self.delay(now)
        if config.reorder > 0 and self._random() < config.reorder:
            self.reordered += 1
            self.held = True
            d += config.reorder_extra
        return d


def datagram_deliver_at(now: float, delay: float, held: bool, last: float) -> float:
    """Delivery time of a datagram: in order (``max(now + delay, last)``, ``last``
    the latest delivery time of its direction so far) unless it was ``held`` back
    to be overtaken."""
    return now + delay if held else max(now + delay, last)


def stream_deliver_at(now: float, delay: float, last: float) -> float:
    """Delivery time of a stream chunk: ``max(now + delay, last)``, so that a byte
    stream is never reordered (a later chunk waits for an earlier, slower one)."""
    return max(now + delay, last)


class StreamScheduler:
    """Non-decreasing delivery times for one byte stream in one direction."""

    def __init__(self, model: DirectionModel):
        self.model = model
        self.last = -math.inf

    def deliver_at(self, now: float) -> float:
        """When a chunk read at ``now`` is to be written out.

        On a stream, ``loss`` is a lost segment that TCP recovers: the chunk comes one
        retransmission timeout (``rto``) late, and the ones behind it wait for it."""
        model = self.model
        delay = model.delay(now)
        model.sent += 1
        if model.config.loss > 0 and model.rng.random() < model.config.loss:
            model.lost += 1
            delay += model.config.rto
        self.last = stream_deliver_at(now, delay, self.last)
        return self.last


class LinkModel:
    """Both directions of a path. ``asymmetry`` (s) is added to ``backward`` only.

    Each direction owns a ``random.Random`` seeded from ``seed`` and its name, so
    a seed reproduces both directions' draws whatever the traffic interleaving.
    """

    def __init__(
        self,
        forward: DirectionConfig,
        backward: DirectionConfig | None = None,
        *,
        asymmetry: float = 0.0,
        seed: int | None = None,
        start: float = 0.0,
    ):
        backward = forward if backward is None else backward
        self.seed = seed
        self.asymmetry = asymmetry
        self.forward = DirectionModel(forward, _rng(seed, "forward"), start=start)
        self.backward = DirectionModel(
            backward, _rng(seed, "backward"), start=start, asymmetry=asymmetry
        )


def _rng(seed: int | None, name: str) -> random.Random:
    return random.Random(None if seed is None else f"{seed}/{name}")


# -- endpoints -----------------------------------------------------------------
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
    example = "expected tcp/HOST:PORT or udp/HOST:PORT, e.g. tcp/127.0.0.1:7447"
    protocol: LinkProtocol | None = None
    rest = text
    if "/" in text:
        proto, _, rest = text.partition("/")
        if proto not in ("tcp", "udp"):
            raise ValueError(f"{text!r}: protocol {proto!r} not supported, {example}")
        protocol = "tcp" if proto == "tcp" else "udp"
    if "#" in rest or "?" in rest:
        raise ValueError(f"{text!r}: endpoint options (# or ?) are not supported, {example}")
    if rest.startswith("["):
        host, sep, port_text = rest[1:].partition("]:")
        if not sep:
            raise ValueError(f"{text!r}: {example}")
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"{text!r}: {host!r} is not an IPv6 address") from None
    else:
        host, sep, port_text = rest.rpartition(":")
        if not sep or not host:
            raise ValueError(f"{text!r}: {example}")
        if ":" in host:
            raise ValueError(f"{text!r}: an IPv6 address needs brackets, e.g. tcp/[::1]:7447")
        if not _HOSTNAME.match(host):
            raise ValueError(f"{text!r}: {host!r} is not a host name or address")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{text!r}: port must be a number 0-65535, not {port_text!r}")
    return LinkEndpoint(protocol, host, int(port_text))


def _endpoint(text: str) -> str:
    parse_endpoint(text)
    return text


# -- options (command-line units) ----------------------------------------------
_NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
_Prob = Annotated[float, Field(ge=0, le=1)]


class LinkOptions(BaseModel):
    """The ``fedlab link`` flags, in the flags' units (ms, s, probabilities)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    listen: Annotated[str, AfterValidator(_endpoint)] = Field(description="where clients connect")
    to: Annotated[str, AfterValidator(_endpoint)] = Field(description="where traffic goes")
    protocol: LinkProtocol | None = Field(
        None, description="tcp or udp; default from the endpoints"
    )
    delay_ms: _NonNeg = Field(0.0, description="base one-way delay, both directions, ms")
    jitter_ms: _NonNeg = Field(0.0, description="jitter scale, both directions, ms")
    jitter_dist: JitterDist = "normal"
    asymmetry_ms: _NonNeg = Field(0.0, description="extra delay of the backward direction, ms")
    loss: _Prob = Field(
        0.0, description="loss probability (udp: dropped; tcp: retransmitted after rto_ms)"
    )
    rto_ms: float = Field(200.0, ge=0, allow_inf_nan=False, description="tcp retransmission, ms")
    reorder: _Prob = Field(0.0, description="datagram reorder probability (udp)")
    reorder_extra_ms: _NonNeg = Field(10.0, description="extra delay of a reordered datagram, ms")
    burst_every: _NonNeg = Field(0.0, description="seconds between bursts; 0: none")
    burst_duration: _NonNeg | None = Field(None, description="burst length, s")
    burst_extra_ms: _NonNeg | None = Field(None, description="extra delay during a burst, ms")
    burst_jitter_factor: _NonNeg = Field(3.0, description="jitter multiplier during a burst")
    backward_delay_ms: _NonNeg | None = Field(None, description="backward base delay, ms")
    backward_jitter_ms: _NonNeg | None = Field(None, description="backward jitter scale, ms")
    backward_loss: _Prob | None = Field(None, description="backward loss probability (udp)")
    seed: int | None = Field(None, ge=0, description="random seed; none: a fresh one")
    duration: float | None = Field(None, gt=0, allow_inf_nan=False, description="run time, s")
    stats_json: Path | None = Field(None, description="counters written here every second")
    max_queue_mib: float = Field(64.0, gt=0, allow_inf_nan=False, description="queue cap, MiB")
    udp_idle: float = Field(60.0, gt=0, allow_inf_nan=False, description="udp session idle, s")

    @model_validator(mode="after")
    def _consistent(self) -> LinkOptions:
        listen, to = parse_endpoint(self.listen), parse_endpoint(self.to)
        given = {p for p in (listen.protocol, to.protocol, self.protocol) if p is not None}
        if len(given) > 1:
            raise ValueError(
                f"--listen {self.listen}, --to {self.to} and --protocol "
                f"{self.protocol or '(unset)'} name different protocols"
            )
        if to.port == 0:
            raise ValueError(f"--to {self.to}: port 0 cannot be dialled")
        if self.proto == "tcp" and self.reorder:
            raise ValueError(
                "--reorder: a TCP stream never reorders bytes; "
                "use --protocol udp (or udp/ endpoints)"
            )
        if self.burst_every == 0:
            for flag, value in (
                ("--burst-duration", self.burst_duration),
                ("--burst-extra-ms", self.burst_extra_ms),
            ):
                if value is not None:
                    raise ValueError(f"{flag}: needs --burst-every S (bursts are off)")
        elif self.burst_length >= self.burst_every:
            raise ValueError(
                f"--burst-duration: {self.burst_length} s"
                f"{' (the default)' if self.burst_duration is None else ''} must be shorter than "
                f"--burst-every {self.burst_every} s"
            )
        return self

    @property
    def proto(self) -> LinkProtocol:
        return (
            self.protocol
            or parse_endpoint(self.listen).protocol
            or parse_endpoint(self.to).protocol
            or "tcp"
        )

    @property
    def burst_length(self) -> float:
        return 5.0 if self.burst_duration is None else self.burst_duration

    def direction(self, name: Literal["forward", "backward"]) -> DirectionConfig:
        """The model settings of one direction, in seconds (asymmetry not included)."""
        back = name == "backward"
        delay = self.delay_ms
        jitter = self.jitter_ms
        loss = self.loss
        if back:
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

    def model(self, seed: int, start: float) -> LinkModel:
        return LinkModel(
            self.direction("forward"),
            self.direction("backward"),
            asymmetry=self.asymmetry_ms / 1e3,
            seed=seed,
            start=start,
        )


def _option_errors(error: ValidationError) -> str:
    lines = []
    for item in error.errors():
        msg = item["msg"].removeprefix("Value error, ")
        if item["loc"]:
            flag = "--" + str(item["loc"][0]).replace("_", "-")
            got = repr(item["input"])
            lines.append(f"{flag}: {msg}" if got in msg else f"{flag}: {msg} (got {got})")
        else:
            lines.append(msg)
    return "\n".join(lines)


def options_from_args(args: argparse.Namespace) -> LinkOptions:
    """Validate the parsed flags; a ConfigError names the flag and the reason."""
    data = {
        name: getattr(args, name)
        for name in LinkOptions.model_fields
        if getattr(args, name, None) is not None
    }
    try:
        return LinkOptions.model_validate(data)
    except ValidationError as error:
        raise ConfigError(_option_errors(error)) from None


# -- statistics ----------------------------------------------------------------
@dataclass(slots=True)
class DirectionStats:
    """Counters of one direction (bytes and chunks as read from the source)."""

    bytes: int = 0
    chunks: int = 0
    delivered_bytes: int = 0
    delivered: int = 0
    dropped: int = 0
    queued_bytes: int = 0
    max_queued_bytes: int = 0
    pauses: int = 0


@dataclass(slots=True)
class LinkStats:
    """Counters of a running link; ``snapshot`` gives them as JSON-ready data."""

    protocol: LinkProtocol
    listen: str
    to: str
    seed: int
    started: float
    connections: int = 0
    active: int = 0
    refused: int = 0
    forward: DirectionStats = field(default_factory=DirectionStats)
    backward: DirectionStats = field(default_factory=DirectionStats)

    def snapshot(self, now: float, model: LinkModel) -> dict[str, Any]:
        unit = "chunks" if self.protocol == "tcp" else "datagrams"
        out: dict[str, Any] = {
            "protocol": self.protocol,
            "listen": self.listen,
            "to": self.to,
            "seed": self.seed,
            "uptime_s": round(now - self.started, 3),
            "connections": self.connections,
            "active": self.active,
            "refused": self.refused,
        }
        for name, stats, direction in (
            ("forward", self.forward, model.forward),
            ("backward", self.backward, model.backward),
        ):
            out[name] = {
                "bytes": stats.bytes,
                unit: stats.chunks,
                "delivered_bytes": stats.delivered_bytes,
                f"delivered_{unit}": stats.delivered,
                "lost": direction.lost,
                "reordered": direction.reordered,
                "dropped": stats.dropped,
                "queued_bytes": stats.queued_bytes,
                "max_queued_bytes": stats.max_queued_bytes,
                "pauses": stats.pauses,
            }
        return out


def _summary(snap: dict[str, Any]) -> str:
    unit = "chunks" if snap["protocol"] == "tcp" else "datagrams"
    lines = [
        f"fedlab link: stopped after {snap['uptime_s']:.1f} s, "
        f"{'connections' if unit == 'chunks' else 'clients'}: {snap['connections']}, "
        f"refused: {snap['refused']}"
    ]
    for name in ("forward", "backward"):
        d = snap[name]
        lines.append(
            f"  {name}: {d['bytes']} bytes in {d[unit]} {unit}, "
            f"{d['delivered_bytes']} delivered, lost {d['lost']}, reordered {d['reordered']}, "
            f"dropped {d['dropped']}, max queued {d['max_queued_bytes']} bytes"
        )
    return "\n".join(lines)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    except OSError as error:
        log.warning("cannot write %s: %s", path, error)


# -- TCP relay -----------------------------------------------------------------
class _Relay:
    """Shared state of a running link: loop, model, counters, queue cap."""

    def __init__(self, options: LinkOptions, loop: asyncio.AbstractEventLoop, seed: int):
        self.options = options
        self.loop = loop
        self.model = options.model(seed, start=loop.time())
        self.stats = LinkStats(options.proto, options.listen, options.to, seed, loop.time())
        self.limit = int(options.max_queue_mib * 2**20)
        self.target = parse_endpoint(options.to)


class _StreamPipe:
    """One direction of one TCP connection: a FIFO of ``(deliver_at, chunk)``.

    Delivery times never decrease (:class:`StreamScheduler`), so the FIFO is in
    time order; one timer armed for its head drains it.
    """

    def __init__(
        self,
        relay: _Relay,
        model: DirectionModel,
        stats: DirectionStats,
        src: _TcpSide,
        dst: _TcpSide,
    ):
        self.relay = relay
        self.loop = relay.loop
        self.schedule = StreamScheduler(model)
        self.stats = stats
        self.src = src
        self.dst = dst
        self.queue: deque[tuple[float, bytes]] = deque()
        self.queued = 0
        self.timer: asyncio.TimerHandle | None = None
        self.queue_full = False
        self.writer_blocked = False
        self.reading_paused = False
        self.eof = False
        self.close_dst = False
        self.ended = False
        self.dead = False

    def feed(self, data: bytes) -> None:
        if self.dead or self.eof:
            return
        now = self.loop.time()
        at = self.schedule.deliver_at(now)
        n = len(data)
        stats = self.stats
        stats.bytes += n
        stats.chunks += 1
        if not self.queue and at <= now + _EARLY:
            self._write(data)
            return
        self.queue.append((at, data))
        self.queued += n
        stats.queued_bytes += n
        stats.max_queued_bytes = max(stats.max_queued_bytes, stats.queued_bytes)
        if self.timer is None:
            self.timer = self.loop.call_at(at, self._flush)
        if self.queued > self.relay.limit and not self.queue_full:
            self.queue_full = True
            self._update_reading()

    def _write(self, data: bytes) -> None:
        transport = self.dst.transport
        if transport is not None:
            transport.write(data)
            self.stats.delivered_bytes += len(data)
            self.stats.delivered += 1

    def _flush(self) -> None:
        self.timer = None
        if self.dead:
            return
        due = self.loop.time() + _EARLY
        queue = self.queue
        while queue and queue[0][0] <= due:
            _, data = queue.popleft()
            self.queued -= len(data)
            self.stats.queued_bytes -= len(data)
            self._write(data)
        if queue:
            self.timer = self.loop.call_at(queue[0][0], self._flush)
        elif self.eof:
            self._end()
        if self.queue_full and self.queued <= self.relay.limit // 2:
            self.queue_full = False
            self._update_reading()

    def set_writer_blocked(self, blocked: bool) -> None:
        self.writer_blocked = blocked
        self._update_reading()

    def _update_reading(self) -> None:
        pause = (self.queue_full or self.writer_blocked) and not self.dead
        transport = self.src.transport
        if pause == self.reading_paused or transport is None:
            return
        self.reading_paused = pause
        if pause:
            self.stats.pauses += 1
            transport.pause_reading()
        else:
            transport.resume_reading()

    def finish(self, close: bool) -> None:
        """The source has ended: after the queue drains, end (or close) the destination."""
        self.eof = True
        self.close_dst = self.close_dst or close
        if not self.queue and not self.dead:
            self._end()

    def _end(self) -> None:
        if self.ended:
            return
        self.ended = True
        transport = self.dst.transport
        if transport is not None and not transport.is_closing():
            if self.close_dst or not transport.can_write_eof():
                transport.close()
            else:
                transport.write_eof()
        self.src.conn.pipe_ended()

    def abort(self) -> None:
        """Drop what is queued (its destination is gone)."""
        self.dead = True
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        self.stats.queued_bytes -= self.queued
        self.stats.dropped += len(self.queue)
        self.queue.clear()
        self.queued = 0


class _TcpSide(asyncio.Protocol):
    """One socket of a relayed connection: ``a`` accepted, ``b`` dialled to ``--to``."""

    def __init__(self, conn: _TcpConnection, name: Literal["a", "b"]):
        self.conn = conn
        self.name = name
        self.transport: asyncio.Transport | None = None
        self.out: _StreamPipe | None = None  # reads from this side
        self.into: _StreamPipe | None = None  # writes into this side
        self.lost = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.conn.made(self)

    def data_received(self, data: bytes) -> None:
        if self.out is not None:
            self.out.feed(data)

    def eof_received(self) -> bool:
        if self.out is not None:
            self.out.finish(close=False)
        return True  # keep the socket open: the other direction may still carry data

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = True
        self.conn.side_lost(self, exc)

    def pause_writing(self) -> None:
        if self.into is not None:
            self.into.set_writer_blocked(True)

    def resume_writing(self) -> None:
        if self.into is not None:
            self.into.set_writer_blocked(False)


class _TcpConnection:
    """An accepted connection ``a`` relayed to its own connection ``b`` to ``--to``."""

    def __init__(self, relay: _Relay, registry: set[_TcpConnection]):
        self.relay = relay
        self.registry = registry
        self.a = _TcpSide(self, "a")
        self.b = _TcpSide(self, "b")
        self.dial: asyncio.Task[None] | None = None
        self.closed = False
        self.peer = "?"

    def made(self, side: _TcpSide) -> None:
        relay = self.relay
        if side is self.a:
            assert side.transport is not None
            self.peer = str(side.transport.get_extra_info("peername"))
            if len(self.registry) >= _MAX_SESSIONS:
                relay.stats.refused += 1
                log.warning("refusing %s: %d connections open", self.peer, _MAX_SESSIONS)
                self.closed = True
                side.transport.abort()
                return
            self.registry.add(self)
            relay.stats.connections += 1
            relay.stats.active += 1
            side.transport.pause_reading()  # until the other end is connected
            self.dial = relay.loop.create_task(self._dial())
            return
        # b connected: wire both directions, then let a's bytes flow.
        assert self.a.transport is not None
        model = relay.model
        fwd = _StreamPipe(relay, model.forward, relay.stats.forward, self.a, self.b)
        bwd = _StreamPipe(relay, model.backward, relay.stats.backward, self.b, self.a)
        self.a.out = self.b.into = fwd
        self.b.out = self.a.into = bwd
        self.a.transport.resume_reading()

    async def _dial(self) -> None:
        target = self.relay.target
        try:
            await asyncio.wait_for(
                self.relay.loop.create_connection(lambda: self.b, target.host, target.port),
                _DIAL_TIMEOUT,
            )
        except (TimeoutError, OSError) as error:
            log.warning("cannot reach %s for %s: %s", target, self.peer, error)
            if self.a.transport is not None:
                self.a.transport.close()
            return
        if self.closed and self.b.transport is not None:
            self.b.transport.close()

    def pipe_ended(self) -> None:
        """Both directions half-closed and drained: close the connection."""
        fwd, bwd = self.a.out, self.b.out
        if fwd is not None and bwd is not None and fwd.ended and bwd.ended:
            self.close()

    def side_lost(self, side: _TcpSide, exc: Exception | None) -> None:
        if exc is not None:
            log.debug("connection %s side %s lost: %s", self.peer, side.name, exc)
        if side.into is not None:
            side.into.abort()
        if side.out is not None:
            side.out.finish(close=True)  # deliver what is queued, then close the other side
        other = self.b if side is self.a else self.a
        if side is self.a and self.dial is not None and not self.dial.done():
            self.closed = True
            self.dial.cancel()
        if other.transport is None or other.lost:
            self._forget()
        elif other.out is None:
            other.transport.close()

    def close(self) -> None:
        """Close both sockets now (what is queued is dropped)."""
        self.closed = True
        if self.dial is not None and not self.dial.done():
            self.dial.cancel()
        for side in (self.a, self.b):
            if side.into is not None:
                side.into.abort()
            if side.transport is not None and not side.transport.is_closing():
                side.transport.close()
        if self.b.transport is None:
            self._forget()

    def _forget(self) -> None:
        if self in self.registry:
            self.registry.discard(self)
            self.relay.stats.active -= 1


async def _serve_tcp(relay: _Relay, stop: asyncio.Event, ready: Callable[[str], None]) -> None:
    listen = parse_endpoint(relay.options.listen)
    connections: set[_TcpConnection] = set()

    def accept() -> _TcpSide:
        return _TcpConnection(relay, connections).a

    try:
        server = await relay.loop.create_server(
            accept, listen.host, listen.port, reuse_address=True
        )
    except OSError as error:
        raise ConfigError(f"--listen {relay.options.listen}: cannot listen: {error}") from None
    sockname = server.sockets[0].getsockname()
    ready(str(LinkEndpoint("tcp", sockname[0], sockname[1])))
    try:
        await stop.wait()
    finally:
        server.close()
        for conn in list(connections):
            conn.close()
        await server.wait_closed()
        for _ in range(3):  # let connection_lost callbacks run
            await asyncio.sleep(0)


# -- UDP relay -----------------------------------------------------------------
@dataclass(eq=False, slots=True)
class _UdpSession:
    client: Any
    sock: socket.socket
    last: float
    closed: bool = False


class _DatagramQueue:
    """One direction's datagrams by delivery time: a heap, in arrival order except
    for the ones the model held back (``--reorder``)."""

    def __init__(
        self,
        relay: _Relay,
        model: DirectionModel,
        stats: DirectionStats,
        send: Callable[[_UdpSession, bytes], bool],
        pause: Callable[[bool], None],
    ):
        self.relay = relay
        self.loop = relay.loop
        self.model = model
        self.stats = stats
        self.send = send
        self.pause = pause
        self.heap: list[tuple[float, int, _UdpSession, bytes]] = []
        self.seq = 0
        self.last_at = -math.inf  # delivery time of the latest datagram not held back
        self.timer: asyncio.TimerHandle | None = None
        self.timer_at = math.inf
        self.full = False

    def push(self, session: _UdpSession, data: bytes, now: float) -> None:
        stats = self.stats
        stats.bytes += len(data)
        stats.chunks += 1
        delay = self.model.sample(now)
        if delay is None:
            return
        at = datagram_deliver_at(now, delay, self.model.held, self.last_at)
        if not self.model.held:
            self.last_at = at
        if not self.heap and at <= now + _EARLY:
            self._send(session, data)
            return
        heapq.heappush(self.heap, (at, self.seq, session, data))
        self.seq += 1
        stats.queued_bytes += len(data)
        stats.max_queued_bytes = max(stats.max_queued_bytes, stats.queued_bytes)
        if at < self.timer_at:
            if self.timer is not None:
                self.timer.cancel()
            self.timer = self.loop.call_at(at, self._flush)
            self.timer_at = at
        if stats.queued_bytes > self.relay.limit and not self.full:
            self.full = True
            stats.pauses += 1
            self.pause(True)

    def _send(self, session: _UdpSession, data: bytes) -> None:
        if not session.closed and self.send(session, data):
            self.stats.delivered_bytes += len(data)
            self.stats.delivered += 1
        else:
            self.stats.dropped += 1

    def _flush(self) -> None:
        self.timer = None
        self.timer_at = math.inf
        heap = self.heap
        due = self.loop.time() + _EARLY
        while heap and heap[0][0] <= due:
            _, _, session, data = heapq.heappop(heap)
            self.stats.queued_bytes -= len(data)
            self._send(session, data)
        if heap:
            self.timer_at = heap[0][0]
            self.timer = self.loop.call_at(self.timer_at, self._flush)
        if self.full and self.stats.queued_bytes <= self.relay.limit // 2:
            self.full = False
            self.pause(False)

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        self.stats.dropped += len(self.heap)
        self.stats.queued_bytes = 0
        self.heap.clear()


class _UdpRelay:
    """Datagrams from each client address relayed through a socket of their own."""

    def __init__(self, relay: _Relay, sock: socket.socket, target: tuple[Any, ...], family: int):
        self.relay = relay
        self.loop = relay.loop
        self.sock = sock
        self.target = target
        self.family = family
        self.sessions: dict[Any, _UdpSession] = {}
        self.paused_fwd = False
        self.paused_bwd = False
        model, stats = relay.model, relay.stats
        self.fwd = _DatagramQueue(relay, model.forward, stats.forward, self._send_fwd, self._pf)
        self.bwd = _DatagramQueue(relay, model.backward, stats.backward, self._send_bwd, self._pb)
        self.loop.add_reader(sock.fileno(), self._on_listen)

    def _send_fwd(self, session: _UdpSession, data: bytes) -> bool:
        try:
            session.sock.send(data)
        except OSError:  # full buffer or ICMP error: a datagram is lost, as on a real path
            return False
        return True

    def _send_bwd(self, session: _UdpSession, data: bytes) -> bool:
        try:
            self.sock.sendto(data, session.client)
        except OSError:
            return False
        return True

    def _pf(self, pause: bool) -> None:
        self.paused_fwd = pause
        if pause:
            self.loop.remove_reader(self.sock.fileno())
        else:
            self.loop.add_reader(self.sock.fileno(), self._on_listen)

    def _pb(self, pause: bool) -> None:
        self.paused_bwd = pause
        for session in self.sessions.values():
            if pause:
                self.loop.remove_reader(session.sock.fileno())
            else:
                self.loop.add_reader(session.sock.fileno(), self._on_reply, session)

    def _on_listen(self) -> None:
        for _ in range(_READ_BATCH):
            try:
                data, addr = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                log.debug("udp receive: %s", error)
                return
            now = self.loop.time()
            session = self.sessions.get(addr)
            if session is None:
                session = self._open(addr, now)
                if session is None:
                    self.relay.stats.forward.dropped += 1
                    continue
            session.last = now
            self.fwd.push(session, data, now)

    def _open(self, addr: Any, now: float) -> _UdpSession | None:
        stats = self.relay.stats
        if len(self.sessions) >= _MAX_SESSIONS:
            stats.refused += 1
            return None
        sock = socket.socket(self.family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.connect(self.target)
        except OSError as error:
            sock.close()
            log.warning("cannot open a socket to %s: %s", self.relay.target, error)
            stats.refused += 1
            return None
        session = _UdpSession(addr, sock, now)
        self.sessions[addr] = session
        stats.connections += 1
        stats.active += 1
        if not self.paused_bwd:
            self.loop.add_reader(sock.fileno(), self._on_reply, session)
        return session

    def _on_reply(self, session: _UdpSession) -> None:
        for _ in range(_READ_BATCH):
            try:
                data = session.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:  # e.g. ICMP port unreachable from the target
                log.debug("udp reply to %s: %s", session.client, error)
                continue
            now = self.loop.time()
            session.last = now
            self.bwd.push(session, data, now)

    def sweep(self, now: float) -> None:
        """Close sessions idle for longer than ``udp_idle`` seconds."""
        idle = self.relay.options.udp_idle
        for addr, session in list(self.sessions.items()):
            if now - session.last > idle:
                self._close_session(addr, session)

    def _close_session(self, addr: Any, session: _UdpSession) -> None:
        del self.sessions[addr]
        session.closed = True
        if not self.paused_bwd:
            self.loop.remove_reader(session.sock.fileno())
        session.sock.close()
        self.relay.stats.active -= 1

    def close(self) -> None:
        self.fwd.close()
        self.bwd.close()
        if not self.paused_fwd:
            self.loop.remove_reader(self.sock.fileno())
        for addr, session in list(self.sessions.items()):
            self._close_session(addr, session)
        self.sock.close()


async def _serve_udp(
    relay: _Relay, stop: asyncio.Event, ready: Callable[[str], None], tick: list[Callable[[], None]]
) -> None:
    listen, target = parse_endpoint(relay.options.listen), relay.target
    loop = relay.loop
    try:
        infos = await loop.getaddrinfo(target.host, target.port, type=socket.SOCK_DGRAM)
    except OSError as error:
        raise ConfigError(f"--to {relay.options.to}: cannot resolve: {error}") from None
    family, _, _, _, target_addr = infos[0]
    try:
        linfos = await loop.getaddrinfo(listen.host, listen.port, type=socket.SOCK_DGRAM)
        lfamily, _, _, _, listen_addr = linfos[0]
        sock = socket.socket(lfamily, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.bind(listen_addr)
        except OSError:
            sock.close()
            raise
    except OSError as error:
        raise ConfigError(f"--listen {relay.options.listen}: cannot listen: {error}") from None
    udp = _UdpRelay(relay, sock, target_addr, family)
    tick.append(lambda: udp.sweep(loop.time()))
    sockname = sock.getsockname()
    ready(str(LinkEndpoint("udp", sockname[0], sockname[1])))
    try:
        await stop.wait()
    finally:
        udp.close()


# -- running -------------------------------------------------------------------
async def serve(
    options: LinkOptions,
    stop: asyncio.Event,
    ready: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the link until ``stop`` is set (or ``options.duration`` passes).

    ``ready`` is called with the listening endpoint (its real port when 0 was
    asked for) once traffic is accepted. Returns the final counters.
    """
    loop = asyncio.get_running_loop()
    seed = options.seed if options.seed is not None else secrets.randbits(32)
    relay = _Relay(options, loop, seed)

    def announce(endpoint: str) -> None:
        log.info(
            "%s -> %s, seed %d, forward %s, backward %s (+%g ms asymmetry)",
            endpoint,
            options.to,
            seed,
            _describe(options.direction("forward")),
            _describe(options.direction("backward")),
            options.asymmetry_ms,
        )
        if ready is not None:
            ready(endpoint)

    tick: list[Callable[[], None]] = []

    def write_stats() -> None:
        if options.stats_json is not None:
            _write_json(options.stats_json, relay.stats.snapshot(loop.time(), relay.model))

    async def ticker() -> None:
        deadline = None if options.duration is None else loop.time() + options.duration
        while not stop.is_set():
            wait = 1.0 if deadline is None else min(1.0, deadline - loop.time())
            if wait <= 0:
                stop.set()
                break
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), wait)
            for fn in tick:
                fn()
            write_stats()

    ticker_task = loop.create_task(ticker())
    try:
        if options.proto == "tcp":
            await _serve_tcp(relay, stop, announce)
        else:
            await _serve_udp(relay, stop, announce, tick)
    finally:
        stop.set()
        ticker_task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await ticker_task
    write_stats()
    return relay.stats.snapshot(loop.time(), relay.model)


def _describe(config: DirectionConfig) -> str:
    text = f"{config.delay * 1e3:g} ms"
    if config.jitter:
        text += f" + {config.jitter_dist} jitter {config.jitter * 1e3:g} ms"
    if config.loss:
        text += f", loss {config.loss:g}"
    if config.reorder:
        text += f", reorder {config.reorder:g}"
    return text


def run_link(options: LinkOptions, ready: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the link in its own event loop until SIGINT, SIGTERM or ``duration``."""
    # select(2) rather than epoll: microsecond timers (see the module docstring).
    loop = asyncio.SelectorEventLoop(selectors.SelectSelector())
    stop = asyncio.Event()
    signals = (signal.SIGINT, signal.SIGTERM)
    try:
        for sig in signals:
            loop.add_signal_handler(sig, stop.set)
        return loop.run_until_complete(serve(options, stop, ready))
    finally:
        for sig in signals:
            loop.remove_signal_handler(sig)
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.close()


def cmd_link(args: argparse.Namespace) -> int:
    """``fedlab link``: validate the flags, run, print the counters."""
    options = options_from_args(args)

    def ready(endpoint: str) -> None:
        print(f"fedlab link: listening on {endpoint} -> {options.to}", flush=True)

    snap = run_link(options, ready)
    print(_summary(snap), flush=True)
    return 0


# -- command line --------------------------------------------------------------
def register(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
    formatter_class: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    """Add the ``link`` command. It opens no Zenoh session, so ``add_zenoh_flags`` is unused."""
    del add_zenoh_flags
    p = subparsers.add_parser(
        "link",
        help="emulate an internet path (delay, jitter, loss) between two lab routers",
        formatter_class=formatter_class,
        description=(
            "Relay traffic from --listen to --to, delayed and jittered per direction like\n"
            "netem. forward: from clients of --listen towards --to; backward: the replies.\n"
            "TCP (Zenoh router links) gets delay, jitter, bursts and loss as retransmission\n"
            "delay (--rto-ms), never reordering;\n"
            "UDP also gets loss and reordering. --asymmetry-ms slows the backward direction\n"
            "only: an offset estimate is then off by half of it, and cannot tell."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab link --listen tcp/127.0.0.1:7450 --to tcp/127.0.0.1:7447 \\\n"
            "      --delay-ms 40 --jitter-ms 5 --burst-every 180 --burst-extra-ms 20\n"
            "  fedlab router --lab rome -l tcp/127.0.0.1:7448 -e tcp/127.0.0.1:7450\n"
            "  fedlab link --listen udp/[::1]:9000 --to udp/[::1]:9001 --loss 0.01 --reorder 0.02"
        ),
    )
    p.add_argument(
        "--listen",
        required=True,
        default=argparse.SUPPRESS,
        metavar="ENDPOINT",
        help="e.g. tcp/127.0.0.1:7450",
    )
    p.add_argument(
        "--to",
        required=True,
        default=argparse.SUPPRESS,
        metavar="ENDPOINT",
        help="e.g. tcp/127.0.0.1:7447",
    )
    p.add_argument(
        "--protocol",
        choices=["tcp", "udp"],
        default=argparse.SUPPRESS,
        help="default: from the endpoints, else tcp",
    )
    # Flags without a default stay unset (the model's default or the other direction's).
    _unset: dict[str, Any] = {"type": float, "default": argparse.SUPPRESS}
    g = p.add_argument_group("path (both directions unless --backward-*)")
    g.add_argument("--delay-ms", type=float, default=0.0, metavar="D", help="base one-way delay")
    g.add_argument("--jitter-ms", type=float, default=0.0, metavar="J", help="jitter scale")
    g.add_argument(
        "--jitter-dist",
        choices=["normal", "exp", "pareto"],
        default="normal",
        help="normal: |N(0,J)|; exp: mean J; pareto: heavy tail, mean J",
    )
    g.add_argument(
        "--asymmetry-ms", type=float, default=0.0, metavar="A", help="added to backward only"
    )
    g.add_argument(
        "--loss",
        type=float,
        default=0.0,
        metavar="P",
        help="loss: udp drops the datagram; tcp delivers it one --rto-ms late (retransmission)",
    )
    g.add_argument(
        "--rto-ms", type=float, default=200.0, metavar="MS", help="tcp retransmission timeout"
    )
    g.add_argument("--reorder", type=float, default=0.0, metavar="P", help="reorder (udp)")
    g.add_argument(
        "--reorder-extra-ms",
        type=float,
        default=10.0,
        metavar="D",
        help="how long a reordered datagram is held back",
    )
    g.add_argument(
        "--backward-delay-ms", **_unset, metavar="D", help="backward base delay (--delay-ms)"
    )
    g.add_argument(
        "--backward-jitter-ms", **_unset, metavar="J", help="backward jitter (--jitter-ms)"
    )
    g.add_argument("--backward-loss", **_unset, metavar="P", help="backward loss (--loss)")
    b = p.add_argument_group("bursts (the paper saw larger deviations every ~3 minutes)")
    b.add_argument(
        "--burst-every", type=float, default=0.0, metavar="S", help="seconds between bursts"
    )
    b.add_argument("--burst-duration", **_unset, metavar="S", help="burst length (5 s)")
    b.add_argument("--burst-extra-ms", **_unset, metavar="D", help="extra delay in a burst (0)")
    b.add_argument(
        "--burst-jitter-factor",
        type=float,
        default=3.0,
        metavar="F",
        help="jitter multiplier in a burst",
    )
    r = p.add_argument_group("run")
    r.add_argument(
        "--seed", type=int, default=argparse.SUPPRESS, metavar="N", help="random seed (fresh)"
    )
    r.add_argument("--duration", **_unset, metavar="S", help="stop after S seconds (never)")
    r.add_argument(
        "--stats-json",
        type=Path,
        default=argparse.SUPPRESS,
        metavar="FILE",
        help="write the counters here every second and at exit",
    )
    r.add_argument(
        "--max-queue-mib",
        type=float,
        default=64.0,
        metavar="M",
        help="per-direction queue above which a side stops being read",
    )
    r.add_argument(
        "--udp-idle", type=float, default=60.0, metavar="S", help="forget idle UDP clients"
    )
    p.set_defaults(func=cmd_link)

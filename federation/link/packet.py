"""The packet-level impairment stage: what happens to each IPv4 packet crossing an
emulated internet path. Pure: ``now`` is passed in; no sockets, clocks or threads
(the TUN device loop is :mod:`federation.link.tun`).

Unlike the relays of ``fedlab link`` (which terminate TCP, so a lab's own TCP
never sees loss or the real round trip), this stage acts on IP packets between
two network stacks: a dropped segment is recovered by the labs' kernels, with
their retransmission timers, fast retransmit and back-off.

One direction of the path (:class:`PacketPath`), for a packet of ``n`` bytes
offered at ``now``:

1. **cut**: dropped while the path is cut (a schedule of ``(at, length)``
   windows after ``start``, or :meth:`PacketPath.set_cut`);
2. **MTU**: dropped if ``n > mtu``; with ``icmp`` and the DF bit set, an ICMP
   "fragmentation needed" (type 3, code 4, RFC 1191) goes back to the sender,
   without it the path is a black hole;
3. **loss**: a two-state Gilbert model. In the good state a packet is lost with
   probability ``loss_good``; a loss enters the bad state, which lasts a geometric
   number of packets of mean ``loss_burst``, all lost. With ``loss_burst = 1``
   losses are independent. The overall loss rate is ``loss`` (:func:`gilbert`);
4. **rate**: a ``rate`` bytes/s bottleneck serializes packets (``n / rate``
   seconds each) behind a FIFO of at most ``queue`` bytes (tail drop);
5. **delay**: the base delay, jitter and reordering of
   :class:`federation.link.model.DirectionModel` (netem's model: a jittered
   packet never overtakes an earlier one unless ``reorder`` holds it back).

The delivery time is then

.. math::

    t_\\text{out} = \\max(t_\\text{link}, t) + n / r + d, \\qquad
    t_\\text{link} \\leftarrow \\max(t_\\text{link}, t) + n / r

with ``d`` from the delay model (in order unless held back).
"""

from __future__ import annotations

import heapq
import ipaddress
import math
import random
import struct
from dataclasses import dataclass, field
from typing import Literal

from federation.link.model import DirectionModel, datagram_deliver_at
from schemas.link import DirectionConfig, JitterDist

__all__ = [
    "Drop",
    "IPv4Header",
    "PacketOptions",
    "PacketPath",
    "PacketStage",
    "Verdict",
    "checksum",
    "frag_needed",
    "gilbert",
    "parse_ipv4",
]

Drop = Literal["cut", "mtu", "loss", "queue", "malformed"]
"""Why a packet was dropped."""

_MIN_MTU = 68  # RFC 791: every IPv4 link carries 68 bytes
_NON_NEGATIVE = ("delay", "jitter", "reorder_extra", "rate")  # PacketOptions' finite >= 0
_PROBABILITIES = ("loss", "reorder")  # PacketOptions' in [0, 1]


@dataclass(frozen=True)
class PacketOptions:
    """One direction of the path. Seconds, bytes, probabilities.

    Raises ValueError naming the field for a value out of range.
    """

    delay: float = 0.0  # base one-way delay, s
    jitter: float = 0.0  # jitter scale, s (see jitter_dist)
    jitter_dist: JitterDist = "normal"
    loss: float = 0.0  # long-run loss probability
    loss_burst: float = 1.0  # mean length of a run of losses, packets (1: independent)
    reorder: float = 0.0  # probability a packet is held back reorder_extra
    reorder_extra: float = 0.010  # s
    rate: float = 0.0  # bottleneck, bytes/s; 0: unlimited
    queue: int = 256 * 1024  # bottleneck FIFO, bytes
    mtu: int = 0  # largest packet carried, bytes; 0: no limit
    icmp: bool = True  # answer a too-big DF packet with ICMP "fragmentation needed"
    cuts: tuple[tuple[float, float], ...] = ()  # (at, length) after start, s

    def __post_init__(self) -> None:
        self._check_ranges()
        self._check_loss_burst()
        self._check_sizes()
        self._check_cuts()

    def _check_ranges(self) -> None:
        for name in _NON_NEGATIVE:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, not {value!r}")
        for name in _PROBABILITIES:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], not {value!r}")

    def _check_loss_burst(self) -> None:
        if self.loss >= 1.0 and self.loss_burst > 1:
            raise ValueError("loss 1 cannot come in bursts: use loss_burst 1")
        if not (math.isfinite(self.loss_burst) and self.loss_burst >= 1):
            raise ValueError(f"loss_burst must be >= 1 packet, not {self.loss_burst!r}")

    def _check_sizes(self) -> None:
        if self.queue < 0:
            raise ValueError(f"queue must be >= 0 bytes, not {self.queue!r}")
        if self.mtu and self.mtu < _MIN_MTU:
            raise ValueError(f"mtu must be 0 (none) or >= {_MIN_MTU} bytes, not {self.mtu!r}")

    def _check_cuts(self) -> None:
        for at, length in self.cuts:
            if not (math.isfinite(at) and at >= 0 and math.isfinite(length) and length > 0):
                raise ValueError(f"cuts: ({at!r}, {length!r}) must be (at >= 0, length > 0) s")

    def direction_config(self) -> DirectionConfig:
        """The delay model's settings (loss is this module's, so none there)."""
        return DirectionConfig(
            delay=self.delay,
            jitter=self.jitter,
            jitter_dist=self.jitter_dist,
            reorder=self.reorder,
            reorder_extra=self.reorder_extra,
        )


def gilbert(loss: float, burst: float) -> tuple[float, float]:
    """(p, r) of the Gilbert model with loss rate ``loss`` and mean run ``burst``.

    Good state: lost with probability ``p`` (then to the bad state). Bad state:
    every packet lost; it ends after each packet with probability ``r = 1 / burst``.
    The stationary loss rate is :math:`\\pi_B + \\pi_G p` where a loss starts a run of
    mean length ``burst`` packets, so a fraction ``loss`` of packets is lost when

    .. math:: p = \\frac{\\ell}{\\ell + b (1 - \\ell)}

    (:math:`\\ell` = ``loss``, :math:`b` = ``burst``). With ``burst = 1``, ``p = loss``.
    """
    if loss <= 0:
        return 0.0, 1.0
    if loss >= 1:
        return 1.0, 0.0
    return loss / (loss + burst * (1.0 - loss)), 1.0 / burst


# -- IPv4 -------------------------------------------------------------------------
@dataclass(frozen=True)
class IPv4Header:
    """The fields of an IPv4 header this stage needs."""

    src: str
    dst: str
    protocol: int  # 1 ICMP, 6 TCP, 17 UDP
    length: int  # total length, bytes
    header_length: int  # bytes
    dont_fragment: bool


def parse_ipv4(packet: bytes) -> IPv4Header:
    """The header of an IPv4 packet; ValueError saying why if it is not one."""
    if len(packet) < 20:
        raise ValueError(f"{len(packet)} bytes: shorter than an IPv4 header")
    version, ihl = packet[0] >> 4, (packet[0] & 0x0F) * 4
    if version != 4:
        raise ValueError(f"IP version {version}, not 4")
    if ihl < 20 or ihl > len(packet):
        raise ValueError(f"header length {ihl} out of range")
    (length,) = struct.unpack_from("!H", packet, 2)
    (flags,) = struct.unpack_from("!H", packet, 6)
    return IPv4Header(
        src=str(ipaddress.IPv4Address(packet[12:16])),
        dst=str(ipaddress.IPv4Address(packet[16:20])),
        protocol=packet[9],
        length=length,
        header_length=ihl,
        dont_fragment=bool(flags & 0x4000),
    )


def checksum(data: bytes) -> int:
    """The Internet checksum (RFC 1071) of ``data``."""
    if len(data) % 2:
        data += b"\0"
    total: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def frag_needed(packet: bytes, mtu: int, router: str) -> bytes:
    """The ICMP "fragmentation needed" (type 3, code 4) a router at ``router`` sends
    back for ``packet`` that does not fit its next hop's ``mtu`` (RFC 792, RFC 1191):
    the offending header and its first 8 data bytes, the MTU in bytes 6-7."""
    head = parse_ipv4(packet)
    quoted = packet[: head.header_length + 8]
    icmp = struct.pack("!BBHHH", 3, 4, 0, 0, mtu) + quoted
    icmp = icmp[:2] + struct.pack("!H", checksum(icmp)) + icmp[4:]
    total = 20 + len(icmp)
    ip = struct.pack(
        "!BBHHHBBH4s4s",
        0x45,
        0xC0,  # DSCP CS6 (network control), as routers send ICMP
        total,
        0,
        0,
        64,
        1,
        0,
        ipaddress.IPv4Address(router).packed,
        ipaddress.IPv4Address(head.src).packed,
    )
    ip = ip[:10] + struct.pack("!H", checksum(ip)) + ip[12:]
    return ip + icmp


# -- one direction ----------------------------------------------------------------
@dataclass
class Verdict:
    """What becomes of one packet: delivered at ``at`` (s, the clock of ``now``), or
    dropped for ``drop``; ``reply`` is an ICMP error to send back, if any."""

    at: float | None
    drop: Drop | None = None
    reply: bytes | None = None


@dataclass
class PathCounters:
    offered: int = 0
    delivered: int = 0
    bytes: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    icmp_sent: int = 0
    reordered: int = 0


class PacketPath:
    """One direction of the path; ``now`` always passed in (seconds, any clock)."""

    def __init__(self, options: PacketOptions, rng: random.Random, *, start: float = 0.0):
        self.options = options
        self.rng = rng
        self.start = start
        self.model = DirectionModel(options.direction_config(), rng, start=start)
        self.p_enter, self.p_leave = gilbert(options.loss, options.loss_burst)
        self.bad = False  # in a loss run
        self.cut_now = False  # cut by set_cut, beside the schedule
        self.link_free = -math.inf  # when the bottleneck has sent what it holds
        self.last = -math.inf  # latest in-order delivery
        self.counters = PathCounters()

    def set_cut(self, cut: bool) -> None:
        """Cut the path (every packet dropped) or restore it, beside the schedule."""
        self.cut_now = cut

    def is_cut(self, now: float) -> bool:
        t = now - self.start
        return self.cut_now or any(at <= t < at + n for at, n in self.options.cuts)

    def _lost(self) -> bool:
        if self.bad:
            if self.rng.random() >= self.p_leave:
                return True
            self.bad = False  # this packet is a good-state one: it may start a new run
        if self.p_enter > 0 and self.rng.random() < self.p_enter:
            self.bad = self.options.loss_burst > 1
            return True
        return False

    def _drop(self, reason: Drop) -> Verdict:
        self.counters.dropped[reason] = self.counters.dropped.get(reason, 0) + 1
        return Verdict(None, reason)

    def offer(self, packet: bytes, now: float, router: str | None = None) -> Verdict:
        """The fate of ``packet`` entering the path at ``now``; ``router`` is the address
        an ICMP error comes from (none: no ICMP error is ever sent)."""
        self.counters.offered += 1
        opts = self.options
        n = len(packet)
        if self.is_cut(now):
            return self._drop("cut")
        if opts.mtu and n > opts.mtu:
            return self._too_big(packet, router)
        if self._lost():
            return self._drop("loss")
        begin = self._through_bottleneck(n, now)
        if begin is None:
            return self._drop("queue")
        return self._deliver(n, begin)

    def _too_big(self, packet: bytes, router: str | None) -> Verdict:
        """Dropped for the MTU. With ``icmp`` and a ``router``, a DF packet that is not
        ICMP itself gets "fragmentation needed" back (ICMP never answers ICMP)."""
        verdict = self._drop("mtu")
        if not self.options.icmp or router is None:
            return verdict
        try:
            head = parse_ipv4(packet)
        except ValueError:
            return verdict
        if head.dont_fragment and head.protocol != 1:
            verdict.reply = frag_needed(packet, self.options.mtu, router)
            self.counters.icmp_sent += 1
        return verdict

    def _through_bottleneck(self, n: int, now: float) -> float | None:
        """When an ``n``-byte packet offered at ``now`` has left the bottleneck (``now``
        without one), or None if it does not fit the bottleneck's FIFO (tail drop)."""
        opts = self.options
        if opts.rate <= 0:
            return now
        backlog = max(0.0, self.link_free - now) * opts.rate
        if backlog + n > opts.queue:
            return None
        self.link_free = max(self.link_free, now) + n / opts.rate
        return self.link_free

    def _deliver(self, n: int, begin: float) -> Verdict:
        """An ``n``-byte packet leaving the bottleneck at ``begin``, delivered after the
        delay model's delay (held back with probability ``reorder``)."""
        opts = self.options
        delay = self.model.delay(begin)
        held = opts.reorder > 0 and self.rng.random() < opts.reorder
        if held:
            delay += opts.reorder_extra
            self.counters.reordered += 1
        at = datagram_deliver_at(begin, delay, held, self.last)
        if not held:
            self.last = at
        self.counters.delivered += 1
        self.counters.bytes += n
        return Verdict(at)


class PacketStage:
    """Both directions between two networks, and the packets in flight.

    A packet whose destination is in ``forward_net`` takes the ``forward`` path, any
    other the ``backward`` one. :meth:`offer` schedules a packet; :meth:`due` pops
    those whose time has come, in delivery order; :meth:`next_due` says when the
    next one is.
    """

    def __init__(
        self,
        forward: PacketOptions,
        backward: PacketOptions | None = None,
        *,
        forward_net: str,
        router: str | None = None,
        seed: int | None = None,
        start: float = 0.0,
    ):
        self.forward_net = ipaddress.IPv4Network(forward_net)
        self.router = router
        self.forward = PacketPath(forward, _rng(seed, "forward"), start=start)
        self.backward = PacketPath(
            forward if backward is None else backward, _rng(seed, "backward"), start=start
        )
        self.malformed = 0
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = 0

    def path(self, dst: str) -> PacketPath:
        forward = ipaddress.IPv4Address(dst) in self.forward_net
        return self.forward if forward else self.backward

    def set_cut(self, cut: bool) -> None:
        self.forward.set_cut(cut)
        self.backward.set_cut(cut)

    def offer(self, packet: bytes, now: float) -> Verdict:
        """Schedule ``packet`` (read at ``now``); an ICMP reply is scheduled too, on
        the opposite path's delay."""
        try:
            head = parse_ipv4(packet)
        except ValueError:
            self.malformed += 1
            return Verdict(None, "malformed")
        path = self.path(head.dst)
        verdict = path.offer(packet, now, self.router)
        if verdict.at is not None:
            self._push(verdict.at, packet)
        if verdict.reply is not None:
            back = self.backward if path is self.forward else self.forward
            self._push(now + back.model.base, verdict.reply)
        return verdict

    def _push(self, at: float, packet: bytes) -> None:
        self._seq += 1
        heapq.heappush(self._queue, (at, self._seq, packet))

    def next_due(self) -> float | None:
        return self._queue[0][0] if self._queue else None

    def due(self, now: float) -> list[bytes]:
        out = []
        while self._queue and self._queue[0][0] <= now:
            out.append(heapq.heappop(self._queue)[2])
        return out

    def __len__(self) -> int:
        return len(self._queue)

    def snapshot(self) -> dict[str, object]:
        """Counters of both directions, JSON-ready."""

        def one(p: PacketPath) -> dict[str, object]:
            c = p.counters
            return {
                "offered": c.offered,
                "delivered": c.delivered,
                "bytes": c.bytes,
                "dropped": dict(c.dropped),
                "icmp_sent": c.icmp_sent,
                "reordered": c.reordered,
                "cut": p.cut_now,
            }

        return {
            "forward": one(self.forward),
            "backward": one(self.backward),
            "malformed": self.malformed,
            "in_flight": len(self._queue),
        }


def _rng(seed: int | None, name: str) -> random.Random:
    return random.Random(None if seed is None else f"{seed}/packet/{name}")

"""The link emulator's path model: delays, jitter, bursts, loss and reordering, and
when each chunk or datagram is delivered. Pure: ``now`` is always passed in; no
sockets, clocks or threads.

Directions
----------
``forward`` carries what the listening side's clients send towards the target;
``backward`` carries the replies. Each direction has its own
:class:`DirectionModel`; ``asymmetry`` is added to the backward direction only.

Asymmetry is the real limit of every offset estimate (Eq. 4 assumes equal trips):
with trips ``d_f`` and ``d_b`` the estimated offset is off by ``(d_f - d_b) / 2``,
and nothing at the application layer can see it. A link with ``asymmetry = A``
lets a test check that the estimator's reported error bound covers ``A / 2``.

Delay
-----
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

Delivery
--------
Datagrams (:class:`DatagramScheduler`) are lost with probability ``loss`` and,
with probability ``reorder``, held ``reorder_extra`` seconds longer so the ones
sent after them overtake them. Otherwise a direction delivers datagrams in the
order they came (:func:`datagram_deliver_at`): jitter stretches the gaps between
them but never swaps two, as netem's FIFO queue does. Reordering is thus only
what ``reorder`` asks for; Zenoh's UDP links do not reorder, and a declaration
overtaken by what it declares is dropped (routers linked through a jittery
reordering relay exchanged almost nothing).

Byte streams (:class:`StreamScheduler`) are never lost or reordered: a chunk is
delivered at ``max(now + d, previous delivery)``; a "lost" chunk comes one
retransmission timeout ``rto`` late, as TCP recovers a lost segment.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable

from schemas.link import DirectionConfig, JitterDist, LinkOptions

__all__ = [
    "PARETO_SHAPE",
    "DatagramScheduler",
    "DirectionModel",
    "LinkModel",
    "StreamScheduler",
    "datagram_deliver_at",
    "stream_deliver_at",
]

PARETO_SHAPE = 1.5
"""Shape of the Pareto (Lomax) jitter: heavy tail, finite mean, infinite variance."""

_JITTER_MEAN = {"normal": math.sqrt(2.0 / math.pi), "exp": 1.0, "pareto": 1.0}


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


class DatagramScheduler:
    """Delivery times of one direction's datagrams: in arrival order, except the ones
    the model holds back (``reorder``); ``None`` for a lost one."""

    def __init__(self, model: DirectionModel):
        self.model = model
        self.last = -math.inf  # delivery time of the latest datagram not held back

    def deliver_at(self, now: float) -> float | None:
        """When a datagram read at ``now`` is to be sent on, or ``None`` if it is lost."""
        model = self.model
        delay = model.sample(now)
        if delay is None:
            return None
        at = datagram_deliver_at(now, delay, model.held, self.last)
        if not model.held:
            self.last = at
        return at


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

    @classmethod
    def from_options(cls, options: LinkOptions, *, seed: int, start: float) -> LinkModel:
        """The model of a link's options (ms converted to s)."""
        return cls(
            options.direction("forward"),
            options.direction("backward"),
            asymmetry=options.asymmetry_ms / 1e3,
            seed=seed,
            start=start,
        )


def _rng(seed: int | None, name: str) -> random.Random:
    return random.Random(None if seed is None else f"{seed}/{name}")

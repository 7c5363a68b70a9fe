"""Three-timestamp clock synchronization (paper section 3.1), free of I/O.

One exchange between a client and a server::

    t1  client clock, request sent
    t2  server clock, request received and reply sent (one instant)
    t3  client clock, reply received

.. math::

    \\text{delay} = (t_3 - t_1) / 2                     \\quad\\text{(Eq. 3)}

    \\text{offset} = t_2 - (t_1 + t_3) / 2              \\quad\\text{(Eq. 4)}

``offset`` is server clock minus client clock, so the server's time is
``t_client + offset`` (Eq. 5). If the outbound and return trips differ, the
offset is wrong by half their difference; no application-layer method can see
that, so :attr:`Exchange.error_bound` reports the worst case instead.

Both halves are here. The client, :class:`SyncClient`, matches replies to
requests by the echoed ``t1`` and rejects late, duplicate, unmatched and
malformed ones; an estimator turns accepted exchanges into one offset. The
server, :func:`serve`, answers a request with the paper's 64-byte reply and its
send time ``t2s`` (the optional fourth timestamp) as the reply's attachment;
the client reads that with :func:`read_send_time`. Time is always passed in
(``now``): nothing here reads a clock.
"""

from __future__ import annotations

import bisect
import math
import statistics
from collections import Counter, OrderedDict, deque
from typing import Literal, NamedTuple, Protocol

from federation.core import wire

__all__ = [
    "DEFAULT_WINDOW",
    "DELAY_WINDOW",
    "Estimator",
    "Exchange",
    "PaperEstimator",
    "ServedReply",
    "SyncClient",
    "read_send_time",
    "serve",
]

DEFAULT_WINDOW = 10.0
"""Seconds of reference time over which the paper averages the offset (Eq. 6)."""

DELAY_WINDOW = 50
"""Exchanges whose one-way delays' median is a client's estimate of the link's delay."""


class Exchange:
    """The timestamps of one query/reply, and what they give.

    ``t2s`` is the optional fourth timestamp (server clock when the reply left).
    With it, the server's turnaround ``t2s - t2`` is taken out of the delay and the
    offset is SNTP's; without it, receive and send are one instant (the paper's).

    What they give is computed once, when the exchange is made: each is read
    several times per reply (clock-step check, delay median, clock filter), and
    computed at each read (as properties) they would cost a follower's reply path a
    tenth of its time.
    """

    __slots__ = ("delay", "error_bound", "offset", "rtt", "t1", "t2", "t2s", "t3", "t_mid",
                 "turnaround")  # fmt: skip

    t1: float
    t2: float
    t3: float
    t2s: float | None
    turnaround: float
    """Server's time between receiving the request and sending the reply (s)."""
    rtt: float
    """Round trip on the wire: client's elapsed time less the server's turnaround (s)."""
    delay: float
    """One-way delay, Eq. 3 (s): ``(t3 - t1) / 2``, less half the turnaround if known."""
    offset: float
    """Server clock minus client clock, Eq. 4 (s): ``t2 - (t1 + t3) / 2``; with four
    timestamps ``((t2 - t1) + (t2s - t3)) / 2``."""
    t_mid: float
    """Client time the offset refers to: the middle of the exchange (s)."""
    error_bound: float
    """Largest offset error any path asymmetry can cause: half the round trip."""

    def __init__(self, t1: float, t2: float, t3: float, t2s: float | None = None):
        setattr_ = object.__setattr__
        turnaround = 0.0 if t2s is None else t2s - t2
        rtt = (t3 - t1) - turnaround
        setattr_(self, "t1", t1)
        setattr_(self, "t2", t2)
        setattr_(self, "t3", t3)
        setattr_(self, "t2s", t2s)
        setattr_(self, "turnaround", turnaround)
        setattr_(self, "rtt", rtt)
        delay = rtt / 2.0
        setattr_(self, "delay", delay)
        setattr_(self, "error_bound", delay)
        setattr_(self, "offset", ((t2 - t1) + ((t2 if t2s is None else t2s) - t3)) / 2.0)
        setattr_(self, "t_mid", (t1 + t3) / 2.0)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"Exchange is immutable: cannot set {name!r}")

    def __eq__(self, other: object) -> bool:
        if other.__class__ is not Exchange:
            return NotImplemented
        return (self.t1, self.t2, self.t3, self.t2s) == (other.t1, other.t2, other.t3, other.t2s)

    def __hash__(self) -> int:
        return hash((self.t1, self.t2, self.t3, self.t2s))

    def __repr__(self) -> str:
        return f"Exchange(t1={self.t1!r}, t2={self.t2!r}, t3={self.t3!r}, t2s={self.t2s!r})"

    def __reduce__(self) -> tuple[type[Exchange], tuple[float, float, float, float | None]]:
        return Exchange, (self.t1, self.t2, self.t3, self.t2s)


class Estimator(Protocol):
    """Turns accepted exchanges into a clock offset, a function of the client's time."""

    def add(self, exchange: Exchange) -> None: ...

    @property
    def offset(self) -> float | None:
        """The offset at the latest exchange (s)."""

    def offset_at(self, t: float) -> float | None:
        """The offset at client time ``t`` (s); differs from ``offset`` if drift is modelled."""

    @property
    def bound(self) -> float | None:
        """Half the mean round-trip excess over the minimum of the samples used (s):
        the scale of error queueing leaves in the estimate."""

    @property
    def locked(self) -> bool: ...

    def reset(self) -> None: ...


class PaperEstimator:
    """The paper's estimate (Eq. 6): the mean (or median) of the offsets measured
    during the first ``window`` seconds of reference time, held constant afterwards.

    The window is measured on the server's clock (``t2``) from the first accepted
    exchange: the server is the reference. Until the window closes, the estimate is
    the statistic of the samples so far, so an agent has a usable offset at once.
    """

    def __init__(
        self, statistic: Literal["mean", "median"] = "mean", window: float = DEFAULT_WINDOW
    ):
        if statistic not in ("mean", "median"):
            raise ValueError(f"statistic must be 'mean' or 'median', not {statistic!r}")
        if not window > 0:
            raise ValueError(f"window must be positive seconds, not {window!r}")
        self.statistic = statistic
        self.window = window
        self.reset()

    def reset(self) -> None:
        self._samples: list[float] = []
        self._rtts: list[float] = []
        self._start: float | None = None
        self._held: float | None = None

    def add(self, exchange: Exchange) -> None:
        if self._held is not None:
            return
        if self._start is None:
            self._start = exchange.t2
        if exchange.t2 - self._start > self.window:
            self._held = self._compute()
            return
        self._samples.append(exchange.offset)
        self._rtts.append(exchange.rtt)

    def _compute(self) -> float | None:
        if not self._samples:
            return None
        if self.statistic == "median":
            return statistics.median(self._samples)
        return math.fsum(self._samples) / len(self._samples)

    @property
    def offset(self) -> float | None:
        return self._held if self._held is not None else self._compute()

    def offset_at(self, t: float) -> float | None:
        return self.offset

    @property
    def bound(self) -> float | None:
        if not self._rtts:
            return None
        least = min(self._rtts)
        return math.fsum(r - least for r in self._rtts) / len(self._rtts) / 2.0

    @property
    def locked(self) -> bool:
        """True once the window has closed and the offset is held."""
        return self._held is not None


class ServedReply(NamedTuple):
    """The server's answer to one request."""

    payload: bytes
    """The reply (64 bytes): ``t1`` echoed, ``t2``, the server's pose."""
    attachment: bytes
    """The send time ``t2s`` (8 bytes, coded as a request): the payload stays the paper's."""


def serve(
    request: bytes | bytearray | memoryview, t2: float, pose: wire.Pose, now: float
) -> ServedReply:
    """The server half of an exchange: answer ``request``, received at ``t2``, with
    ``pose``, the reply leaving at ``now`` (all on the server's clock, s).

    Raises :class:`~federation.core.wire.DecodeError` for a malformed request. A
    server answering on another's behalf (a bridge) passes that clock's ``t2``."""
    t1 = wire.decode_request(request)
    return ServedReply(wire.encode_reply(t1, t2, pose), wire.encode_request(now))


def read_send_time(attachment: bytes | bytearray | memoryview) -> float:
    """The server's send time ``t2s`` from a reply's attachment (s, server clock).

    Raises :class:`~federation.core.wire.DecodeError` if it is not one."""
    return wire.decode_request(attachment)


MAX_OFFSET = 1e10
"""s (317 years): the largest offset between two clocks a reply may give; clocks on
the Unix epoch are 1.8e9 s from one that starts at 0."""


def _send_time(t2s: float | None, t2: float, t1: float, t3: float) -> float | None:
    """The server's send time ``t2s`` if the exchange can have had it (finite, not before
    ``t2``, the turnaround not longer than the client's wait ``t3 - t1``); else None:
    the exchange uses three timestamps."""
    if t2s is not None and not (math.isfinite(t2s) and 0.0 <= t2s - t2 <= t3 - t1):
        return None
    return t2s


def _unusable(exchange: Exchange) -> str | None:
    """Why a matched exchange gives nothing to estimate from, or None."""
    if exchange.t3 < exchange.t1:  # our own clock went back while the request was out
        return "clock_step"
    if not (math.isfinite(exchange.offset) and math.isfinite(exchange.delay)):
        # Finite timestamps whose differences overflow (a t2 near the float's limit):
        # nothing to estimate from, and nothing the delay window could order.
        return "malformed"
    if abs(exchange.offset) > MAX_OFFSET:
        # No two clocks of a federation are centuries apart; such a t2 would only
        # overflow the estimator's sums (every pose stamped with an offset of inf).
        return "implausible"
    return None


class SyncClient:
    """Client side of the exchange with one server.

    ``request(now)`` gives the payload to send; ``receive(payload, now)`` takes a
    reply and returns the decoded reply once the exchange is accepted, or ``None`` if
    it was rejected (``rejected`` counts why). Pending requests older than ``timeout``
    are expired by ``expire(now)`` (also called by ``request``) and counted in
    ``timeouts``; a reply to one is late.
    """

    _HISTORY = 256  # answered and expired t1 values remembered to classify rejects
    STEP_CONFIRM = 3  # inconsistent exchanges in a row that make a clock step

    def __init__(
        self,
        estimator: Estimator,
        timeout: float = 0.5,
        delay_window: int = DELAY_WINDOW,
        step_margin: float = 0.002,
    ):
        if not timeout > 0:
            raise ValueError(f"timeout must be positive seconds, not {timeout!r}")
        if delay_window < 1:
            raise ValueError(f"delay_window must be at least 1 exchange, not {delay_window!r}")
        self.estimator = estimator
        self.timeout = timeout
        self.sent = 0
        self.timeouts = 0
        self.accepted = 0
        self.rejected: Counter[str] = Counter()
        self.last: Exchange | None = None
        self.last_rejection: str | None = None
        self.steps = 0  # clock steps detected
        # Whether the last accepted exchange reached the estimate (False: held back by
        # the warm-up until three agree).
        self.last_fed = False
        self.last_step: float | None = None  # size of the last one (s)
        self.step_margin = step_margin
        self._suspects: list[Exchange] = []
        self._warmup: list[Exchange] = []  # the first exchanges, until three agree
        # The recent exchanges' offsets and error bounds, side by side (sorted in C).
        self._recent: deque[float] = deque(maxlen=8)
        self._recent_bounds: deque[float] = deque(maxlen=8)
        self._delays = _Median(delay_window)  # the recent exchanges' one-way delays
        self._pending: OrderedDict[float, None] = OrderedDict()
        self._answered: OrderedDict[float, None] = OrderedDict()
        self._expired: OrderedDict[float, None] = OrderedDict()
        self._last_t1 = -math.inf

    def request(self, now: float) -> bytes:
        self.expire(now)
        # t1 is the request's identity: keep it unique even if the clock repeats.
        t1 = now if now > self._last_t1 else math.nextafter(self._last_t1, math.inf)
        self._last_t1 = t1
        self._pending[t1] = None
        self.sent += 1
        return wire.encode_request(t1)

    def sent_here(self, t1: float) -> bool:
        """Whether ``t1`` is one of this client's own recent requests (pending, answered
        or expired): a request carrying it came back to its sender."""
        return t1 in self._pending or t1 in self._answered or t1 in self._expired

    def expire(self, now: float) -> None:
        while self._pending:
            t1 = next(iter(self._pending))
            if now - t1 <= self.timeout:
                break
            del self._pending[t1]
            self.timeouts += 1
            _remember(self._expired, t1)

    def receive(
        self, payload: bytes | bytearray | memoryview, now: float, t2s: float | None = None
    ) -> wire.SyncReply | None:
        """Match a reply read at ``now`` (t3); on success feed the estimator.

        ``t2s``, the server's send time, makes it a four-timestamp exchange."""
        try:
            reply = wire.decode_reply(payload)
        except wire.DecodeError:
            self._reject("malformed")
            return None
        unmatched = self._match(reply.t1, now)
        if unmatched is not None:
            self._reject(unmatched)
            return None
        exchange = Exchange(reply.t1, reply.t2, now, _send_time(t2s, reply.t2, reply.t1, now))
        unusable = _unusable(exchange)
        if unusable is not None:
            self._reject(unusable)
            return None
        verdict = self._verdict(exchange)
        if verdict == "reject":
            return None
        self.last_fed = verdict == "feed"
        self.accepted += 1
        self.last = exchange
        self._delays.add(exchange.delay)
        if verdict == "feed":
            self.estimator.add(exchange)
        return reply

    def _match(self, t1: float, now: float) -> str | None:
        """Match a reply read at ``now``, echoing ``t1``, to a request of ours: None once
        matched (the request is answered now), else why not: ``late`` (expired, or past
        ``timeout`` though :meth:`expire` has not run yet), ``duplicate`` or
        ``unmatched``."""
        if t1 in self._pending:
            del self._pending[t1]
            if now - t1 > self.timeout:
                _remember(self._expired, t1)
                self.timeouts += 1
                return "late"
            _remember(self._answered, t1)
            return None
        if t1 in self._answered:
            return "duplicate"
        if t1 in self._expired:
            return "late"
        return "unmatched"

    def _verdict(self, exchange: Exchange) -> Literal["feed", "held", "reject"]:
        """Whether a usable exchange feeds the estimate, is held back by the warm-up, or
        is rejected as inconsistent with the recent ones (or starts a clock step)."""
        if len(self._recent) < 3:
            return self._warm_up(exchange)
        return "feed" if self._consistent(exchange) else "reject"

    def _consistent(self, exchange: Exchange) -> bool:
        """Clock-step detection, independent of the estimator. An exchange's offset is
        within its error bound (half its round trip) of the true offset, and so is each
        recent one; an exchange further from the recent ones' median than both bounds
        and a margin together means a clock jumped. ``STEP_CONFIRM`` such exchanges in
        a row are a step: the estimate is reset and starts again from them; fewer are
        rejected as ``inconsistent``."""
        if len(self._recent) >= 3:
            offsets = sorted(self._recent)
            bounds = sorted(self._recent_bounds)
            median, bound = offsets[len(offsets) // 2], bounds[len(bounds) // 2]
            allowed = exchange.error_bound + bound + self.step_margin
            if abs(exchange.offset - median) > allowed:
                self._suspects.append(exchange)
                if len(self._suspects) < self.STEP_CONFIRM:
                    self._reject("inconsistent")
                    return False
                self._restart(exchange.offset - median)
                return True
        self._suspects.clear()
        self._recent.append(exchange.offset)
        self._recent_bounds.append(exchange.error_bound)
        return True

    def _warm_up(self, exchange: Exchange) -> Literal["feed", "held", "reject"]:
        """The first exchanges (after a start or a reset) have no recent ones to be
        checked against, so none reaches the estimate until three agree (as
        :meth:`_consistent` judges): the first two are held back (``held``), and at the
        third the one that disagrees with the other two is dropped as ``inconsistent``
        and the rest fed. One wild reply first (a ``t2`` ten seconds off) thus never
        reaches the estimate, where the paper's window would hold it for good and the
        clock filter weigh it for its whole horizon. A third that disagrees is
        rejected, and ``STEP_CONFIRM`` of them in a row are a clock step during the
        warm-up: they replace the first two (else two exchanges from before a step
        would outvote every one after it for good)."""
        warm = [*self._warmup, exchange]
        if len(warm) < 3:
            self._warmup = warm
            return "held"
        median = sorted(e.offset for e in warm)[1]
        bound = sorted(e.error_bound for e in warm)[1]

        def agrees(e: Exchange) -> bool:
            return abs(e.offset - median) <= e.error_bound + bound + self.step_margin

        if not agrees(exchange):
            self._suspects.append(exchange)
            if len(self._suspects) < self.STEP_CONFIRM:
                self._reject("inconsistent")
                return "reject"
            suspects, self._suspects = self._suspects, []
            self.steps += 1
            self.last_step = suspects[-1].offset - median
            self.accepted += len(suspects) - 1 - len(self._warmup)  # now these are held
            self._warmup = suspects[:-1]
            return self._warm_up(suspects[-1])
        self._suspects.clear()
        kept = [e for e in warm[:-1] if agrees(e)]
        for _ in range(len(warm) - 1 - len(kept)):  # held back and counted: no longer
            self.accepted -= 1
            self._reject("inconsistent")
        if len(kept) < 2:  # not yet three that agree: hold this one back too
            self._warmup = [*kept, exchange]
            return "held"
        self._warmup = []
        for e in (*kept, exchange):
            self._recent.append(e.offset)
            self._recent_bounds.append(e.error_bound)
        for e in kept:
            self.estimator.add(e)
        return "feed"

    def _restart(self, jump: float) -> None:
        """A clock step: forget the estimate, start again from the suspect exchanges."""
        self.steps += 1
        self.last_step = jump
        suspects, self._suspects = self._suspects, []
        self._warmup = []
        self.estimator.reset()
        self._delays.clear()
        self._recent.clear()
        self._recent_bounds.clear()
        for ex in suspects:
            self._recent.append(ex.offset)
            self._recent_bounds.append(ex.error_bound)
        for ex in suspects[:-1]:  # the caller feeds the last one
            self.accepted += 1
            self._delays.add(ex.delay)
            self.estimator.add(ex)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1
        self.last_rejection = reason

    @property
    def offset(self) -> float | None:
        return self.estimator.offset

    def offset_at(self, t: float) -> float | None:
        return self.estimator.offset_at(t)

    @property
    def delay(self) -> float | None:
        """Median one-way delay of the recent exchanges (seconds), None before the
        first; kept up to date as each is accepted (a follower reads it for every pose)."""
        return self._delays.median

    @property
    def pending(self) -> int:
        return len(self._pending)

    def reset(self) -> None:
        """Forget all estimates (after a clock step); counters are kept."""
        self.estimator.reset()
        self._delays.clear()
        self._pending.clear()
        self._recent.clear()
        self._recent_bounds.clear()
        self._suspects.clear()
        self._warmup = []
        self.last = None


class _Median:
    """The median of the last ``window`` values, kept up to date as each is added.

    A follower reads its delay median for every pose it receives. Sorting the window
    at a read (``statistics.median``) would walk every value, each a float object of
    its own, cold in the cache by the time the pose arrives. The window is kept sorted
    beside its arrival order instead: an add touches a handful of values, and a read is
    one attribute (safe from another thread while an add runs). Values must be finite
    (NaN cannot be ordered); ``window`` at least 1."""

    __slots__ = ("_order", "_sorted", "median")

    def __init__(self, window: int):
        if window < 1:
            raise ValueError(f"window must be at least 1 value, not {window!r}")
        self._order: deque[float] = deque(maxlen=window)
        self._sorted: list[float] = []
        self.median: float | None = None

    def add(self, value: float) -> None:
        order, values = self._order, self._sorted
        if len(order) == order.maxlen:
            del values[bisect.bisect_left(values, order[0])]
        order.append(value)
        bisect.insort(values, value)
        n = len(values)
        half = n // 2
        self.median = values[half] if n % 2 else (values[half - 1] + values[half]) / 2.0

    def clear(self) -> None:
        self._order.clear()
        self._sorted.clear()
        self.median = None


def _remember(history: OrderedDict[float, None], t1: float) -> None:
    history[t1] = None
    if len(history) > SyncClient._HISTORY:
        history.popitem(last=False)

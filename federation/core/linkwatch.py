"""The link watch: safe hold while the followed pose is stale, with a threshold
measured on the link; poses too old to steer by; peers alive but silent. Free of I/O.

A follower steers by the poses it receives, predicted over short gaps
(:class:`agents.guidance.HeadingEstimator`). When they stop coming, steering on the
last one would fly blind, so it holds every valve closed:

- **hold** once no pose has arrived for more than the threshold :math:`T`
  (own clock): :math:`t - t_\\text{pose} > T`;
- **resume** once poses flow again *and* a sync exchange with the followed agent
  has completed since the hold began (:math:`t_3 > t_\\text{hold}`): after an
  outage the offset estimate may be off, and a pose on a wrong time base steers
  wrongly.

The threshold
-------------
A fixed threshold is either shorter than ordinary internet loss (150 ms: one lost
pose and a late one) or slower than a real cut. :class:`LinkWatch` measures the
link from the poses themselves (:meth:`LinkWatch.observe`): the pose period
:math:`P` (median gap of the sender's timestamps), the loss rate :math:`p` (poses
missing from the sender's sequence of periods) and the delay variation
:math:`\\sigma` (standard deviation of the arrival gap minus the send gap; a pose
held behind a TCP retransmission, which costs a round trip, shows here). A gap
longer than :math:`nP` needs :math:`n` poses lost in a row, probability
:math:`p^n` per pose, so

.. math::

    n = \\max\\left(n_\\min, \\left\\lceil \\frac{\\ln \\varepsilon}{\\ln p} \\right\\rceil\\right),
    \\qquad
    T = \\operatorname{clip}\\left(n P + \\max(4 \\sigma, m_\\min),\\;
        T_\\text{first},\\; T_\\max\\right)

where :math:`p` is not the measured loss rate but its upper confidence bound
(Wilson's, one-sided 95 %, over the window's expected poses): at 5 % loss a
400-pose window reads under 4.6 % about 4 times in 10, which gives :math:`n = 3`
where 4 is needed, and three poses lost in a row then held the platform (once in
two testbed runs). The bound leaves :math:`n = 3` up to a measured 2 to 3 %, and
costs nothing at a cut beyond :math:`T_\\max`.

With :math:`\\varepsilon` = 1e-4 spurious holds per pose (one per 8 minutes at
20 Hz), :math:`n_\\min = 3` and :math:`m_\\min` = 20 ms. :math:`T_\\max` (0.25 s by
default) bounds how long a real cut goes unnoticed: the hold comes at most
:math:`T_\\max` after the last pose arrived, i.e. within about 300 ms of a cut on a
40 ms path. Until enough poses are seen (:data:`MIN_SAMPLES`), :math:`T` is the
configured ``stale_after``, which is also the floor :math:`T_\\text{first}`.

Stale poses
-----------
After a cut, a reliable link may deliver queued poses in one burst, seconds old.
:meth:`LinkWatch.too_old` says whether a pose's age on arrival (the sender's clock
now, through the offset estimate, minus its timestamp) exceeds the one-way delay
plus :math:`T`: such a pose is dropped before the controller sees it.

Silent peers
------------
:class:`SilenceWatch` tracks, per peer, since when requests have gone unanswered;
a peer whose liveliness token is present but that has answered nothing for
``after`` seconds is silent: an alarm, not a wait.

Nothing is stale before the first pose: an agent waiting for its leader does
not hold. The caller does the holding; an abort overrides the watch (it is
final), so the caller stops consulting it then.
"""

from __future__ import annotations

import bisect
import math
from array import array
from collections import deque
from collections.abc import Hashable
from typing import Literal

__all__ = [
    "EPSILON",
    "MAX_STALE",
    "MIN_SAMPLES",
    "LinkAction",
    "LinkWatch",
    "SilenceWatch",
    "loss_upper_bound",
    "stale_threshold",
]

LinkAction = Literal["stale_hold", "link_resumed"]
"""What the caller must do: hold the platform, or release it."""

EPSILON = 1e-4
"""Spurious holds allowed per pose (the chance of a gap of n lost poses)."""
MAX_STALE = 0.25
"""s, the longest threshold: a cut is held within this of the last pose."""
LOSS_Z = 1.645
"""Standard normal quantile of the loss rate's upper confidence bound (one-sided 95 %)."""
MIN_RUN = 3
"""Poses lost in a row always tolerated (n_min)."""
MIN_MARGIN = 0.020
"""s, the smallest delay-variation margin (m_min): a control tick and scheduling."""
MIN_SAMPLES = 40
"""Pose gaps seen before the threshold is measured rather than configured."""
WINDOW = 400
"""Pose gaps remembered (20 s at 20 Hz)."""


def loss_upper_bound(missing: int, expected: int, z: float = LOSS_Z) -> float:
    """Wilson's upper confidence bound on a loss rate from ``missing`` of ``expected``."""
    if expected <= 0:
        return 1.0
    p, z2 = missing / expected, z * z / expected
    centre = p + z2 / 2
    spread = z * math.sqrt(p * (1 - p) / expected + z2 / (4 * expected))
    return min(1.0, (centre + spread) / (1 + z2))


def stale_threshold(
    period: float,
    loss: float,
    sigma: float,
    floor: float,
    ceiling: float = MAX_STALE,
    epsilon: float = EPSILON,
) -> float:
    """The hold threshold :math:`T` (s) for pose ``period`` (s), ``loss`` rate and
    delay variation ``sigma`` (s), clipped to ``[floor, ceiling]`` (see the module)."""
    if loss <= 0:
        n = MIN_RUN
    elif loss >= 1:
        return ceiling
    else:
        n = max(MIN_RUN, math.ceil(math.log(epsilon) / math.log(loss)))
    t = n * period + max(4.0 * sigma, MIN_MARGIN)
    return min(max(t, floor), max(ceiling, floor))


class LinkWatch:
    """Decides the stale-pose safe hold.

    ``stale_after`` (s) is the threshold until the link is measured, and its floor;
    ``ceiling`` (s) its upper bound (raised to ``stale_after`` if lower).
    """

    def __init__(self, stale_after: float, ceiling: float = MAX_STALE):
        if not stale_after > 0:
            raise ValueError(f"stale_after must be positive seconds, not {stale_after!r}")
        if not ceiling > 0:
            raise ValueError(f"ceiling must be positive seconds, not {ceiling!r}")
        self.stale_after = stale_after
        self.ceiling = max(ceiling, stale_after)
        self.holding = False
        self.since: float | None = None  # own time the hold began (s)
        self.threshold = stale_after  # s, the current T
        self.period: float | None = None  # s, measured pose period
        self.loss = 0.0  # measured loss rate
        self.loss_bound = 0.0  # its upper confidence bound, which sets the threshold
        self.sigma = 0.0  # s, measured delay variation
        self._last: tuple[float, float] | None = None  # (arrived, sent) of the last pose
        self._gaps: deque[tuple[float, float]] = deque(maxlen=WINDOW)  # (send, arrival) gaps
        self._fresh = 0
        # The window's statistics, kept as gaps come and go (a lean agent):
        # the send gaps sorted (their median is the period) and the sums of the
        # jitter less a shift near its mean (no cancellation), summed afresh every
        # WINDOW gaps so that rounding does not accumulate.
        # The send gaps in one float array, not a list of float objects: finding a gap's
        # place then reads a few neighbouring words, not objects strewn over the heap
        # and cold in the cache when the next pose arrives (16 agents in a process).
        self._sends = array("d")
        self._shift = 0.0
        self._sum = 0.0  # sum of (jitter - shift)
        self._sumsq = 0.0  # sum of (jitter - shift)^2
        self._since_exact = 0

    # -- measuring the link ----------------------------------------------------------
    def observe(self, arrived_at: float, sent_at: float) -> None:
        """A followed pose arrived at own time ``arrived_at`` (s), stamped ``sent_at``
        on its sender's clock (s). Out-of-order or repeated poses are not counted."""
        last = self._last
        if last is not None and sent_at <= last[1]:
            return
        self._last = (arrived_at, sent_at)
        if last is None:
            return
        self._add((sent_at - last[1], arrived_at - last[0]))
        self._fresh += 1
        if self._fresh >= 20 and len(self._gaps) >= MIN_SAMPLES:
            self._fresh = 0
            self._measure()

    def _add(self, gap: tuple[float, float]) -> None:
        """Append a (send, arrival) gap to the window, the oldest leaving a full one."""
        gaps, sends = self._gaps, self._sends
        if len(gaps) == WINDOW:
            send, arrival = gaps[0]
            del sends[bisect.bisect_left(sends, send)]
            d = arrival - send - self._shift
            self._sum -= d
            self._sumsq -= d * d
        gaps.append(gap)
        bisect.insort(sends, gap[0])
        self._since_exact += 1
        if self._since_exact >= WINDOW:
            self._exact_sums()
        else:
            d = gap[1] - gap[0] - self._shift
            self._sum += d
            self._sumsq += d * d

    def _exact_sums(self) -> None:
        """The jitter sums recomputed from the window, shifted by its mean."""
        jitter = [a - s for s, a in self._gaps]
        self._shift = math.fsum(jitter) / len(jitter) if jitter else 0.0
        self._sum = math.fsum(j - self._shift for j in jitter)
        self._sumsq = math.fsum((j - self._shift) ** 2 for j in jitter)
        self._since_exact = 0

    def _measure(self) -> None:
        """Period, loss and delay variation of the window (see the module), from the
        statistics kept by :meth:`_add`: no pass over the whole window."""
        sends, n = self._sends, len(self._sends)
        period = sends[n // 2]  # the median: most gaps are one period
        if not period > 0:
            return
        # A gap's slots are max(1, round(gap / period)): one for every gap below 1.4
        # periods, so only the longer ones (the losses) are looked at.
        tail = bisect.bisect_left(sends, 1.4 * period)
        expected = tail + sum(max(1, round(s / period)) for s in sends[tail:])
        self.loss = (expected - n) / expected
        self.loss_bound = loss_upper_bound(expected - n, expected)
        mean = self._sum / n
        self.sigma = math.sqrt(max(0.0, self._sumsq / n - mean * mean))
        self.period = period
        self.threshold = stale_threshold(
            period, self.loss_bound, self.sigma, self.stale_after, self.ceiling
        )

    def too_old(self, age: float, delay: float | None) -> bool:
        """Whether a pose ``age`` seconds old on arrival (sender's clock) is too old to
        steer by: older than the one-way ``delay`` (s; None: unknown, taken as 0)
        plus the threshold."""
        return age > (delay or 0.0) + self.threshold

    # -- deciding --------------------------------------------------------------------
    def update(
        self,
        now: float,
        pose_at: float | None,
        synced_at: float | None,
        threshold: float | None = None,
    ) -> LinkAction | None:
        """The action due at own time ``now`` (s), given when the last followed pose
        arrived (``pose_at``) and when the last sync exchange with its sender
        completed (``synced_at``, its ``t3``), both on the own clock (None: never);
        None if nothing changes. ``threshold`` (s) judges staleness in place of this
        watch's own measurement: agents that share one measured link (one watch that
        observes the poses) each keep a hold of their own."""
        if pose_at is None:
            return None
        stale = now - pose_at > (self.threshold if threshold is None else threshold)
        if stale and not self.holding:
            self.holding, self.since = True, now
            return "stale_hold"
        if not stale and self.holding:
            assert self.since is not None
            if synced_at is not None and synced_at > self.since:
                self.holding = False
                return "link_resumed"
        return None


class SilenceWatch:
    """Peers alive but silent: requests sent, nothing answered for ``after`` s."""

    def __init__(self, after: float = 2.0):
        if not after > 0:
            raise ValueError(f"after must be positive seconds, not {after!r}")
        self.after = after
        self._unanswered: dict[Hashable, float] = {}  # peer -> first request since a reply

    def requested(self, peer: Hashable, now: float) -> None:
        """A request went to ``peer`` at ``now`` (s)."""
        self._unanswered.setdefault(peer, now)

    def answered(self, peer: Hashable) -> None:
        """``peer`` replied."""
        self._unanswered.pop(peer, None)

    def forget(self, peer: Hashable) -> None:
        """``peer`` left (or restarted): nothing is owed."""
        self._unanswered.pop(peer, None)

    def silent_for(self, peer: Hashable, now: float) -> float | None:
        """Seconds ``peer`` has answered nothing, if more than ``after``; else None."""
        since = self._unanswered.get(peer)
        if since is None or now - since <= self.after:
            return None
        return now - since

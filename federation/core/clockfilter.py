"""A clock model that tracks offset and drift from the low-delay exchanges.

The paper averages every offset of the first 10 s and holds it (Eq. 6). Two
things go wrong with that over an internet path: a sample's offset is off by
half the difference of its two trips, which grows with the queueing each trip
met; and a clock that ticks 50 ppm fast walks 30 ms away in 600 s, which a held
constant cannot follow (the paper's own future work).

This estimator follows the references for both problems:

- *delay weighting* (NTP's clock filter, chrony's delay test): a sample's error
  is bounded by its round-trip excess over the window's minimum,
  :math:`|e_i| \\le x_i / 2` with :math:`x_i = r_i - r_{min}`, and queueing is
  never negative, so low round trips carry the least error. Instead of keeping
  only the best samples, each gets the weight

  .. math::

      w_i = \\frac{1}{(x_i + \\epsilon)^2}, \\qquad
      \\epsilon = \\max(\\tfrac{1}{2}\\,x_{(k)}, 10\\,\\mu s), \\quad
      k = \\max(3, 0.02\\,n)

  (:math:`x_{(k)}` the k-th smallest excess of the n in the window), so a quiet
  path averages many samples (as the paper's mean does) and a noisy one listens
  to its fastest exchanges, never to fewer than a few of them;
- *regression* (chrony): over a sliding ``horizon`` of client time, fit

  .. math::

      \\theta(t) = a + b\\,(t - t_{ref})

  by weighted least squares, ``t`` being the middle of each exchange on the
  client's clock. ``b`` is the relative drift (s/s); it is kept only where it
  is significant (``|b| > drift_sigmas`` standard errors) and the samples span
  at least ``min_span`` seconds, else it is 0 and ``a`` is the weighted mean.

The two halves listen to different numbers of exchanges. The offset's floor is
the 4th-fastest exchange's excess (``k = max(3, 0.02 n)``): on a lossy TCP link
most exchanges wait behind a retransmission (an excess of a round trip or more),
and the first seconds may hold only three or four clean ones, which a floor set
by the 11th-fastest would drown (at 20 % loss that left the estimate 1 to 8 ms
off for the first 10 to 20 s). The drift needs many exchanges spread over the
window, so its regression keeps ``k = max(10, 0.02 n)``; and it must pass 2.5
standard errors, not 2: the test runs at every refit on exchanges whose queueing
is correlated, and a spurious slope is extrapolated to the window's end (a
12 ppm slope fitted to a level shift of the path cost 0.5 ms). Both were chosen
by replaying the exchanges recorded in the namespace testbed (loss 1 to 20 %,
cuts, MTU 576) and the simulated paths of ``fedlab bench sync``; docs/protocol.md
gives the figures.

``Fit.bound`` is half the weighted mean round-trip excess of the samples used:
the scale of error queueing can leave in the estimate. Asymmetry of the
minimum path itself cannot be seen from timestamps by any method: every
estimate may carry it unseen (up to half the minimum round trip).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from federation.core.sync import Exchange

__all__ = ["ClockFilter", "Fit"]

FLOOR_QUANTILE = 0.02  # the noise floor: this quantile of the round-trip excess ...
OFFSET_FLOOR_COUNT = 3  # ... but at least the excess of the 4th-fastest (offset)
DRIFT_FLOOR_COUNT = 10  # ... or of the 11th-fastest (drift regression)


@dataclass(frozen=True, slots=True)
class Fit:
    intercept: float  # offset at t_ref (s)
    drift: float  # d(offset)/dt (s/s)
    t_ref: float  # client time (s)
    bound: float  # largest round-trip excess / 2 of the samples used (s)
    used: int  # samples in the fit

    def at(self, t: float) -> float:
        return self.intercept + self.drift * (t - self.t_ref)


class ClockFilter:
    """Offset and drift from the low-delay exchanges of a sliding window.

    Parameters
    ----------
    horizon
        Seconds of client time kept in the window.
    min_span
        Shortest time span (s) of the window for which drift is fitted.
    drift_sigmas
        Standard errors the drift must exceed to be kept (else 0).
    lock_after
        Seconds after the first exchange after which the estimate counts as
        locked (the paper's 10 s sync phase).
    refit
        Seconds of client time between fits once the window holds 50 exchanges;
        the fit's drift carries the estimate between them.
    """

    def __init__(
        self,
        horizon: float = 120.0,
        min_span: float = 20.0,
        drift_sigmas: float = 2.5,
        lock_after: float = 10.0,
        refit: float = 1.0,
    ):
        if not horizon > 0:
            raise ValueError(f"horizon must be positive seconds, not {horizon!r}")
        if not min_span >= 0:
            raise ValueError(f"min_span must be non-negative seconds, not {min_span!r}")
        self.horizon = horizon
        self.min_span = min_span
        self.drift_sigmas = drift_sigmas
        self.lock_after = lock_after
        self.refit = refit
        self.reset()

    def reset(self) -> None:
        self._window = _Rows()  # (t_mid, offset, rtt) of the exchanges in the horizon
        self._first: float | None = None
        self._fit: Fit | None = None
        self._fitted_at = -math.inf  # t_mid of the newest exchange in the last fit

    def add(self, exchange: Exchange) -> None:
        t = exchange.t_mid
        if self._first is None:
            self._first = t
        self._window.append(t, exchange.offset, exchange.rtt)
        self._window.drop_older(t, self.horizon)
        # Refit on the data's own clock, not on demand: once a second of client time
        # (always while the window is young). Live agents and offline replays thus
        # compute identical fits, and a leader with 60 peers is not refitting 600
        # windows a second.
        if len(self._window) < 50 or t - self._fitted_at >= self.refit:
            self._fit = self._compute()
            self._fitted_at = t

    @property
    def fit(self) -> Fit | None:
        """The fit as of the last refit (computed in :meth:`add`)."""
        return self._fit

    def _compute(self) -> Fit | None:
        if not self._window:
            return None
        data = self._window.rows()
        t_ref = float(data[-1, 0])
        x, offset, rtt = data[:, 0] - t_ref, data[:, 1], data[:, 2]
        excess = rtt - rtt.min()
        # Weighted sums as dot products: one call each, no temporary array (a refit
        # runs on a cold cache between messages, where each numpy call costs).
        w = _weights(excess, OFFSET_FLOOR_COUNT)
        total = float(w.sum())
        bound = float(w @ excess) / total / 2.0
        x_mean = float(w @ x) / total
        y_mean = float(w @ offset) / total
        n = len(x)
        slope = 0.0
        if n >= 3 and float(x[-1] - x[0]) >= self.min_span:
            slope = self._drift(x, offset, _weights(excess, DRIFT_FLOOR_COUNT))
        return Fit(y_mean - slope * x_mean, slope, t_ref, bound, n)

    def _drift(self, x: np.ndarray, offset: np.ndarray, w: np.ndarray) -> float:
        """The weighted regression's slope, or 0 where it is not significant."""
        total = float(w.sum())
        dx = x - float(w @ x) / total
        dy = offset - float(w @ offset) / total
        wdx = w * dx
        sxx = float(wdx @ dx)
        if not sxx > 0:
            return 0.0
        slope = float(wdx @ dy) / sxx
        resid = dy - slope * dx
        stderr = math.sqrt(float(w @ (resid * resid)) / (len(x) - 2) / sxx)
        return 0.0 if abs(slope) <= self.drift_sigmas * stderr else slope

    @property
    def offset(self) -> float | None:
        fit = self.fit
        return None if fit is None else fit.intercept

    def offset_at(self, t: float) -> float | None:
        fit = self._fit  # read several times per control step: not through the property
        return None if fit is None else fit.at(t)

    @property
    def bound(self) -> float | None:
        fit = self.fit
        return None if fit is None else fit.bound

    @property
    def drift(self) -> float | None:
        """Relative rate of the server's clock against the client's (s/s)."""
        fit = self.fit
        return None if fit is None else fit.drift

    @property
    def locked(self) -> bool:
        return (
            self._first is not None
            and bool(self._window)
            and self._window.last_t() - self._first >= self.lock_after
        )


def _weights(excess: np.ndarray, count: int) -> np.ndarray:
    """Delay weights :math:`1/(x_i + \\epsilon)^2`: the floor is half the excess of
    the exchange ``count`` places after the fastest (or at the ``FLOOR_QUANTILE``
    quantile, if further), and never under 10 us."""
    k = min(len(excess) - 1, max(count, int(FLOOR_QUANTILE * len(excess))))
    eps = max(0.5 * float(np.partition(excess, k)[k]), 1e-5)
    return np.asarray(1.0 / (excess + eps) ** 2)


class _Rows:
    """The window's exchanges as rows of one float array, oldest first: 24 bytes an
    exchange (a tuple of three floats cost about 150) and no conversion at each fit.
    New rows wait in a short list and join the array when it is read or
    when its oldest row expires (a row written into the array cost each reply more
    than the rest of the filter); the live rows move back to the start when the
    array's end is reached, and the array doubles when they fill more than half
    of it."""

    def __init__(self, capacity: int = 64):
        self._data = np.empty((capacity, 3))
        self._start = 0
        self._end = 0
        self._fresh: list[tuple[float, float, float]] = []
        self._oldest = math.inf  # t of the oldest row, array or list

    def __len__(self) -> int:
        return self._end - self._start + len(self._fresh)

    def append(self, t: float, offset: float, rtt: float) -> None:
        if not self:
            self._oldest = t
        self._fresh.append((t, offset, rtt))

    def _settle(self) -> None:
        """Move the waiting rows into the array."""
        fresh = self._fresh
        if not fresh:
            return
        live = self._end - self._start
        need = live + len(fresh)
        if self._end + len(fresh) > len(self._data):
            capacity = len(self._data)
            while 2 * need > capacity:
                capacity *= 2
            data = np.empty((capacity, 3)) if capacity != len(self._data) else self._data
            data[:live] = self._data[self._start : self._end].copy()
            self._data, self._start, self._end = data, 0, live
        self._data[self._end : self._end + len(fresh)] = fresh
        self._end += len(fresh)
        fresh.clear()

    def drop_older(self, t: float, horizon: float) -> None:
        """Forget the rows more than ``horizon`` seconds before client time ``t``."""
        if not t - self._oldest > horizon:
            return
        self._settle()
        data, start, end = self._data, self._start, self._end
        while start < end and t - data[start, 0] > horizon:
            start += 1
        self._start = start
        self._oldest = float(data[start, 0]) if start < end else math.inf

    def rows(self) -> np.ndarray:
        """The live rows, (t_mid, offset, rtt), a view: valid until the next append."""
        self._settle()
        return self._data[self._start : self._end]

    def last_t(self) -> float:
        if self._fresh:
            return self._fresh[-1][0]
        return float(self._data[self._end - 1, 0])

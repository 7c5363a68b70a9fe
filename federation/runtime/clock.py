"""Execution clock: each agent's own time, starting at 0 when the agent starts.

The paper's platforms start their clocks at arbitrary moments; only differences
matter. ``offset`` and ``drift_ppm`` skew the clock on purpose so a rehearsal on
one machine has clocks as far apart as two labs'::

    t_exec = offset + (source() - start) * (1 + drift_ppm * 1e-6)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

__all__ = ["ExecClock"]


class ExecClock:
    def __init__(
        self,
        offset: float = 0.0,
        drift_ppm: float = 0.0,
        source: Callable[[], float] = time.monotonic,
    ):
        if not math.isfinite(offset):
            raise ValueError(f"clock offset must be finite seconds, not {offset!r}")
        if not (math.isfinite(drift_ppm) and abs(drift_ppm) < 1e5):
            raise ValueError(f"clock drift must be finite and below 1e5 ppm, not {drift_ppm!r}")
        self.offset = offset
        self.rate = 1.0 + drift_ppm * 1e-6
        self.source = source
        self.start = source()

    def now(self) -> float:
        """Execution time (seconds)."""
        return self.at(self.source())

    def at(self, host: float) -> float:
        """Execution time at a given reading of the host source."""
        return self.offset + (host - self.start) * self.rate

    def step(self, seconds: float) -> None:
        """Jump the clock by ``seconds`` (rehearsing a clock that steps)."""
        self.offset += seconds

    def read(self) -> tuple[float, float]:
        """(execution time, host source reading) taken at the same instant."""
        host = self.source()
        return self.at(host), host

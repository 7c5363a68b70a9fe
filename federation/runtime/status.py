"""Status: what an agent reports of its peers' clocks and of its own loop.

:func:`peer_status` turns a sync client's state into the ``peers`` entries of
:class:`schemas.messages.Status` (also used by the UDP bridge);
:func:`loop_stats` summarizes the control loop's lateness for its ``loop`` field.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from federation.core.sync import SyncClient
from schemas.messages import PeerStatus

__all__ = ["loop_stats", "peer_status"]


def peer_status(
    client: SyncClient, t: float, alive: bool, base: float = 0.0, sharing: int = 1
) -> PeerStatus:
    """What a sync client knows of its peer at own time ``t``, as status reports it;
    ``base`` is subtracted from offsets (to report them against another clock than
    ``t``'s); ``sharing`` agents read the client's estimate."""
    offset = client.offset_at(t)
    drift = getattr(client.estimator, "drift", None)  # only the clock filter models drift
    last = client.last
    return PeerStatus(
        offset=None if offset is None else offset - base,
        delay=client.delay,
        bound=client.estimator.bound,
        drift_ppm=None if drift is None else drift * 1e6,
        error_bound=last.error_bound if last else None,
        last_offset=None if last is None else last.offset - base,
        last_delay=last.delay if last else None,
        locked=client.estimator.locked,
        alive=alive,
        samples=client.accepted,
        sent=client.sent,
        timeouts=client.timeouts,
        rejected=sum(client.rejected.values()),
        rejected_by_reason=dict(client.rejected),
        clock_steps=client.steps,
        sharing=sharing,
    )


def loop_stats(rate: float, lateness: Iterable[float] | memoryview) -> dict[str, float]:
    """Control loop timing: ``rate`` (Hz) and the lateness of the recent ticks (s,
    reported in ms as median, 99th percentile and maximum; a buffer of doubles,
    :meth:`FloatRing.values`, is read without a Python float per value)."""
    if isinstance(lateness, memoryview):
        if lateness.format != "d":
            raise TypeError(f"lateness: a buffer of doubles (format 'd'), not {lateness.format!r}")
        late = np.frombuffer(lateness, dtype=float)
    else:
        late = np.fromiter(lateness, dtype=float)
    n = len(late)
    stats = {"rate_hz": rate, "ticks": float(n)}
    if n:
        # Three order statistics by partition, not a sort of the whole window: an
        # agent reports every second over its last 2000 ticks.
        p50, p99 = n // 2, min(n - 1, int(0.99 * n))
        part = np.partition(late, sorted({p50, p99, n - 1}))
        stats |= {
            "late_p50_ms": float(part[p50]) * 1e3,
            "late_p99_ms": float(part[p99]) * 1e3,
            "late_max_ms": float(part[n - 1]) * 1e3,
        }
    return stats

"""Status: what an agent reports of its peers' clocks and of its own loop.

:func:`peer_status` turns a sync client's state into the ``peers`` entries of
:class:`schemas.messages.Status` (also used by the UDP bridge);
:func:`loop_stats` summarizes the control loop's lateness for its ``loop`` field.
"""

from __future__ import annotations

from collections.abc import Iterable

from federation.core.sync import SyncClient
from schemas.messages import PeerStatus

__all__ = ["loop_stats", "peer_status"]


def peer_status(client: SyncClient, t: float, alive: bool, base: float = 0.0) -> PeerStatus:
    """What a sync client knows of its peer at own time ``t``, as status reports it;
    ``base`` is subtracted from offsets (to report them against another clock than
    ``t``'s)."""
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
    )


def loop_stats(rate: float, lateness: Iterable[float]) -> dict[str, float]:
    """Control loop timing: ``rate`` (Hz) and the lateness of the recent ticks (s,
    reported in ms as median, 99th percentile and maximum)."""
    late = sorted(lateness)
    stats = {"rate_hz": rate, "ticks": float(len(late))}
    if late:
        stats |= {
            "late_p50_ms": late[len(late) // 2] * 1e3,
            "late_p99_ms": late[min(len(late) - 1, int(0.99 * len(late)))] * 1e3,
            "late_max_ms": late[-1] * 1e3,
        }
    return stats

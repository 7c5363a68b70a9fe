"""The link emulator's counters: per direction, and for the whole link as JSON-ready
data (``--stats-json``) and as the summary ``fedlab link`` prints at exit. Pure.

A TCP link counts ``chunks`` (what one read returned), a UDP link ``datagrams``;
the JSON names the unit accordingly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from federation.link.model import LinkModel
from schemas.link import LinkProtocol

__all__ = ["DirectionStats", "LinkStats", "summary"]


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

    def read(self, size: int) -> None:
        """Count a chunk or datagram of ``size`` bytes read from the source."""
        self.bytes += size
        self.chunks += 1

    def queue(self, size: int) -> None:
        """Count ``size`` bytes waiting for their delivery time."""
        self.queued_bytes += size
        self.max_queued_bytes = max(self.max_queued_bytes, self.queued_bytes)

    def deliver(self, size: int) -> None:
        """Count a chunk or datagram of ``size`` bytes written to the destination."""
        self.delivered_bytes += size
        self.delivered += 1


def _unit(protocol: str) -> str:
    return "chunks" if protocol == "tcp" else "datagrams"


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
        """The counters at ``now`` (same clock as ``started``), with the model's
        ``lost`` and ``reordered``."""
        unit = _unit(self.protocol)
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


def summary(snap: dict[str, Any]) -> str:
    """A few lines on a :meth:`LinkStats.snapshot`, for a person."""
    unit = _unit(snap["protocol"])
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

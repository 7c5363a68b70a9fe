"""Reading status lines back, and the ground truth a single machine can give.

On one machine every agent's ``t_exec`` is paired with the same host monotonic
clock (``host_monotonic``), so the true offset between two agents is known::

    true offset (server minus client) = (t_exec_s - host_s) - (t_exec_c - host_c)

exact for clocks without drift; with drift, the error is drift times the time
between the two lines (a microsecond per second at 1 ppm), so pick nearby lines.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["clock_line", "last_status", "read_status", "true_offset"]


def read_status(path: str | Path) -> list[dict[str, Any]]:
    """All complete status lines of a ``--status-json`` file (a partial last line is skipped)."""
    path = Path(path)
    if not path.exists():
        return []
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            lines.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return lines


def last_status(path: str | Path) -> dict[str, Any] | None:
    lines = read_status(path)
    return lines[-1] if lines else None


def true_offset(server: dict[str, Any], client: dict[str, Any]) -> float:
    """Server's clock minus client's clock, from one status line of each."""
    return float(
        (server["t_exec"] - server["host_monotonic"])
        - (client["t_exec"] - client["host_monotonic"])
    )


def clock_line(lines: Sequence[dict[str, Any]]) -> tuple[float, float]:
    """(a, b) with ``t_exec = a + b * host_monotonic``, fitted to an agent's status lines.

    An execution clock is exactly linear in host time (offset and drift), so two
    lines determine it; more only average the float rounding.
    """
    if len(lines) < 2:
        raise ValueError("need at least two status lines to recover a clock")
    host = np.array([line["host_monotonic"] for line in lines])
    t = np.array([line["t_exec"] for line in lines])
    b, a = np.polyfit(host - host[0], t - t[0], 1)
    return float(t[0] + a - b * host[0]), float(b)

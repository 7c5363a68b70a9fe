"""How far ahead ``fedlab ctl`` announces a freeze or a resume: far enough that the
command reaches every participant before its instant, so that every lab applies it at
the same instant of the run.

A command from ctl reaches a participant through the routers; its one-way delay is at
most ctl's delay to the reference agent plus the participant's delay to the reference
(each participant reports the median one-way delay of its sync exchanges with the
reference, ``peers[REF].delay`` in its status; ctl measures its own in the burst of
exchanges that tells it the reference time). The lead is

.. math:: \\Delta_{in} = m + k \\, \\max_i (d_{ctl} + d_i)

with margin :data:`LEAD_MARGIN` (ctl's three copies 50 ms apart, an agent's callback
and lock, a loaded core) and factor :data:`LEAD_FACTOR` (a median delay, not its
tail). A participant whose delay is not known counts as :data:`UNKNOWN_DELAY`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["LEAD_FACTOR", "LEAD_MARGIN", "UNKNOWN_DELAY", "Lead", "delays_to", "transition_lead"]

LEAD_MARGIN = 0.25
"""s added to the worst path's delay, however fast the paths."""
LEAD_FACTOR = 2.0
"""The worst path's median delay counts this many times (its tail)."""
UNKNOWN_DELAY = 0.5
"""s counted for a participant whose delay to the reference is not known."""


@dataclass(frozen=True)
class Lead:
    """A lead (s) and the path that set it."""

    seconds: float
    worst: str | None
    """The participant at the end of the slowest path (None: no participant)."""
    path: float
    """s: that path's one-way delay, ctl's to the reference included."""
    unknown: tuple[str, ...] = ()
    """Participants whose delay to the reference is not known."""

    def describe(self) -> str:
        """One line: the lead and why."""
        text = f"{self.seconds:.3f} s ahead"
        if self.worst is not None:
            text += f" (slowest path: to {self.worst}, {self.path * 1e3:.1f} ms one way)"
        if self.unknown:
            text += f"; delay not known for {', '.join(self.unknown)}: {UNKNOWN_DELAY:g} s each"
        return text


def delays_to(
    reference: str, participants: list[str], statuses: Mapping[str, Mapping[str, Any]]
) -> dict[str, float | None]:
    """Each participant's one-way delay to ``reference`` as its status reports it (0 for
    the reference itself; None where not known)."""
    out: dict[str, float | None] = {}
    for agent in participants:
        if agent == reference:
            out[agent] = 0.0
            continue
        peers = (statuses.get(agent) or {}).get("peers") or {}
        delay = (peers.get(reference) or {}).get("delay")
        known = isinstance(delay, int | float) and not isinstance(delay, bool) and delay >= 0
        out[agent] = float(delay) if known and delay is not None else None
    return out


def transition_lead(delays: Mapping[str, float | None], ctl_delay: float) -> Lead:
    """The lead for participants of one-way ``delays`` to the reference, ctl being
    ``ctl_delay`` s from it."""
    unknown = tuple(sorted(a for a, d in delays.items() if d is None))
    paths = {a: ctl_delay + (UNKNOWN_DELAY if d is None else d) for a, d in delays.items()}
    if not paths:
        return Lead(LEAD_MARGIN + LEAD_FACTOR * ctl_delay, None, ctl_delay)
    worst = max(sorted(paths), key=lambda a: paths[a])
    return Lead(LEAD_MARGIN + LEAD_FACTOR * paths[worst], worst, paths[worst], unknown)

"""Contested peers: two sources speaking for one agent, free of I/O.

Each agent owns its keys: its pose samples come from its one Zenoh session and its
sync queryable is declared by that session alone. The lab router's access control
enforces that (docs/deploy.md); this is the second line. If the pose samples on
one agent's key come from two sources, or two repliers answer its sync queries,
someone else speaks for it: an impostor inside the lab, a router whose access
control is off, or two processes started under one name. Which one is genuine
cannot be told in-band, so the peer is **contested** and nothing from it is used:

- a source is whatever identity the sample carries: the Zenoh session id (zid) of
  a reply's replier, the session id in a pose sample's source info (``None`` when
  it carries none); pose and sync are judged separately (a third party's pose
  publisher may carry no source info, its sync replies always name a replier);
- **contested** once two different sources of one channel were heard within
  ``window`` seconds of each other (:math:`|t_a - t_b| \\le t_\\text{window}`);
- **cleared** once ``quiet`` seconds have passed since two sources were last heard
  within the window; or at once when the peer leaves or rejoins the federation
  (its liveliness token: a restarted agent has a new session id), :meth:`forget`.

Times are the caller's monotonic seconds (``now``); nothing here reads a clock.
The caller decides what "not used" means (a follower holds its platform).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, TypeVar

__all__ = ["Channel", "ContestWatch", "Outcome", "in_order"]

K = TypeVar("K")

Channel = Literal["pose", "sync"]
"""What the source spoke on: pose samples, or replies to this agent's sync queries."""

Outcome = Literal["ok", "contested", "held"]
"""``ok``: use the sample; ``contested``: the peer just became contested (drop it and
everything from it so far); ``held``: it was contested already (drop the sample)."""

DEFAULT_WINDOW = 2.0
"""s: two sources heard this close together contest a peer."""
DEFAULT_QUIET = 5.0
"""s without a second source after which a contest clears."""


def in_order(
    last: dict[K, tuple[str | None, float]], peer: K, source: str | None, t: float
) -> bool:
    """Whether ``peer``'s pose stamped ``t`` (its own clock) from ``source`` is newer than
    the last taken from that source, recorded in ``last`` if so. One no newer (a sample
    reordered on the way or delivered twice) would put an older pose in place of a
    newer one; the caller drops it. A pose from another source is taken (its sender
    restarted with a new session and may count time afresh; two sources at once are
    the contest's to judge): the caller forgets ``peer`` when it leaves or rejoins, so a
    restarted sender that carries no source id is taken again from its return."""
    seen = last.get(peer)
    if seen is not None and seen[0] == source and not t > seen[1]:
        return False
    last[peer] = (source, t)
    return True


def _short(source: str | None) -> str:
    return "no source id" if source is None else source[:8]


@dataclass
class _Peer:
    seen: dict[Channel, dict[str | None, float]] = field(default_factory=dict)
    reason: str | None = None  # why it is contested, None when it is not
    speaker: str | None = None  # the last source whose sample was used
    conflict_at: float = 0.0  # last time two sources were heard within the window


class ContestWatch:
    """Which peers are contested, from the sources heard for each.

    ``window`` and ``quiet`` in seconds (positive). :attr:`contests` counts the
    times a peer became contested.
    """

    def __init__(self, window: float = DEFAULT_WINDOW, quiet: float = DEFAULT_QUIET):
        if not window > 0 or not quiet > 0:
            raise ValueError(f"window and quiet must be positive seconds, not {window}, {quiet}")
        self.window, self.quiet = window, quiet
        self.contests = 0
        self._peers: dict[str, _Peer] = {}

    def observe(self, peer: str, channel: Channel, source: str | None, now: float) -> Outcome:
        """``source`` spoke for ``peer`` on ``channel`` at ``now``: may its sample be used?"""
        state = self._peers.get(peer)
        if state is None:
            state = self._peers[peer] = _Peer()
        seen = state.seen.get(channel)
        if seen is None:
            seen = state.seen[channel] = {}
        elif state.reason is None and len(seen) == 1 and source in seen:
            seen[source] = now  # the usual case: the one source heard again, no contest
            return "ok"
        seen[source] = now
        for other in [s for s, t in seen.items() if now - t > self.window]:
            del seen[other]  # heard too long ago to contest this one
        if len(seen) > 1:
            state.conflict_at = now
            if state.reason is None:
                names = ", ".join(sorted(_short(s) for s in seen))
                what = "sync replies" if channel == "sync" else "pose samples"
                state.reason = f"{what} from {len(seen)} sources ({names})"
                self.contests += 1
                return "contested"
            return "held"
        if self.reason(peer, now) is not None:
            return "held"
        return "ok"

    def new_speaker(self, peer: str, source: str | None) -> bool:
        """Record that ``source`` spoke for ``peer`` in a sample that was used (observed
        ``ok``); True if it is not the source that did last (the first heard, or a new
        session after :meth:`forget`: the peer restarted). None (no source id) is never
        news."""
        state = self._peers.get(peer)
        if source is None or state is None or state.speaker == source:
            return False
        state.speaker = source
        return True

    def speaker(self, peer: str) -> str | None:
        """The last source whose sample was used for ``peer`` (None: none yet)."""
        state = self._peers.get(peer)
        return None if state is None else state.speaker

    def reason(self, peer: str, now: float) -> str | None:
        """Why ``peer`` is contested at ``now``, or None if it is not (clears a contest
        quiet for ``quiet`` seconds)."""
        state = self._peers.get(peer)
        if state is None or state.reason is None:
            return None
        if now - state.conflict_at >= self.quiet:
            state.reason = None
            return None
        return state.reason

    def contested(self, now: float) -> dict[str, str]:
        """Every contested peer and why, at ``now``."""
        out = {}
        for peer in list(self._peers):
            reason = self.reason(peer, now)
            if reason is not None:
                out[peer] = reason
        return out

    def forget(self, peer: str) -> None:
        """``peer`` left or rejoined: its next session starts with a clean record."""
        self._peers.pop(peer, None)

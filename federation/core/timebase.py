"""Time bases: this agent's clock, reference (simulation) time and a peer's clock.

Every agent keeps one offset estimate per peer it syncs with (Eq. 4, filtered),
the peer's clock minus its own, as a function of its own clock ``t``:

.. math::

    o_p(t) = t_p - t

The reference agent's clock is simulation time (Eq. 5); on the reference itself
the offset is zero. Going from one clock to another passes through these offsets,
each evaluated at the present own time :math:`t`:

.. math::

    t_\\text{sim} = t + o_\\text{ref}(t)                        \\quad\\text{(Eq. 5)}

    t_p = t + o_p(t)

    s_\\text{sim} = s_p - o_p(t) + o_\\text{ref}(t)

where :math:`s_p` is a time on peer :math:`p`'s clock (a pose sample's stamp)
and :math:`s_\\text{sim}` the same instant on simulation time. Any answer is None
while an estimate it needs is missing.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from typing import Generic, Protocol, TypeVar

__all__ = ["OffsetEstimate", "TimeBase"]

K = TypeVar("K", bound=Hashable)


class OffsetEstimate(Protocol):
    """A peer's clock minus one's own, as a function of one's own clock (a
    :class:`~federation.core.sync.SyncClient` or an estimator is one)."""

    def offset_at(self, t: float) -> float | None:
        """The offset (s) at own time ``t`` (s); None before any estimate."""


class TimeBase(Generic[K]):
    """Maps between one agent's clock, reference time and its peers' clocks.

    ``me`` and ``reference`` name agents (any hashable key); ``estimates`` maps
    each peer to its offset estimate and is read at each call, so it may be the
    caller's live table of peers. Every method takes the own clock's present ``t``
    (s), at which the estimates are evaluated.
    """

    def __init__(self, me: K, reference: K, estimates: Mapping[K, OffsetEstimate]):
        self.me = me
        self.reference = reference
        self.estimates = estimates

    def offset(self, peer: K, t: float) -> float | None:
        """``peer``'s clock minus own at own time ``t`` (s): 0 for oneself."""
        if peer is self.me or peer == self.me:
            return 0.0
        estimate = self.estimates.get(peer)
        return None if estimate is None else estimate.offset_at(t)

    def reference_offset(self, t: float) -> float | None:
        """Reference clock minus own at own time ``t`` (s): 0 on the reference."""
        return self.offset(self.reference, t)

    def sim_time(self, t: float) -> float | None:
        """Simulation time at own time ``t`` (Eq. 5), s."""
        offset = self.offset(self.reference, t)  # read each control step: one call less
        return None if offset is None else t + offset

    def peer_time(self, peer: K, t: float) -> float | None:
        """``peer``'s clock at own time ``t``, s."""
        offset = self.offset(peer, t)
        return None if offset is None else t + offset

    def peer_to_sim(self, peer: K, s: float, t: float) -> float | None:
        """Time ``s`` on ``peer``'s clock as simulation time, with the estimates at
        own time ``t``, s."""
        to_peer = self.offset(peer, t)
        to_reference = self.reference_offset(t)
        if to_peer is None or to_reference is None:
            return None
        return s - to_peer + to_reference

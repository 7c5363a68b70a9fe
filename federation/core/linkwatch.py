"""The link watch: safe hold while the followed pose is stale, free of I/O.

A follower steers by the poses it receives. When they stop coming, steering on
the last one would fly blind, so it holds every valve closed:

- **hold** once no pose has arrived for more than ``stale_after`` seconds
  (own clock): :math:`t - t_\\text{pose} > t_\\text{stale}`;
- **resume** once poses flow again *and* a sync exchange with the followed agent
  has completed since the hold began (:math:`t_3 > t_\\text{hold}`): after an
  outage the offset estimate may be off, and a pose on a wrong time base steers
  wrongly.

Nothing is stale before the first pose: an agent waiting for its leader does
not hold. The caller does the holding; an abort overrides the watch (it is
final), so the caller stops consulting it then.
"""

from __future__ import annotations

from typing import Literal

__all__ = ["LinkAction", "LinkWatch"]

LinkAction = Literal["stale_hold", "link_resumed"]
"""What the caller must do: hold the platform, or release it."""


class LinkWatch:
    """Decides the stale-pose safe hold; ``stale_after`` in seconds."""

    def __init__(self, stale_after: float):
        if not stale_after > 0:
            raise ValueError(f"stale_after must be positive seconds, not {stale_after!r}")
        self.stale_after = stale_after
        self.holding = False
        self.since: float | None = None  # own time the hold began (s)

    def update(
        self, now: float, pose_at: float | None, synced_at: float | None
    ) -> LinkAction | None:
        """The action due at own time ``now`` (s), given when the last followed pose
        arrived (``pose_at``) and when the last sync exchange with its sender
        completed (``synced_at``, its ``t3``), both on the own clock (None: never);
        None if nothing changes."""
        if pose_at is None:
            return None
        stale = now - pose_at > self.stale_after
        if stale and not self.holding:
            self.holding, self.since = True, now
            return "stale_hold"
        if not stale and self.holding:
            assert self.since is not None
            if synced_at is not None and synced_at > self.since:
                self.holding = False
                return "link_resumed"
        return None

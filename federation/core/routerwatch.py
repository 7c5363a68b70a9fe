"""Whether a session still has its router, from Zenoh's transport and link events.

When an agent's own router dies, every other agent's liveliness token goes with it:
without this, all the agent logs is ``agent X left`` for each of them, as if they had
stopped. Zenoh reports a router's transport (with its kind) and each of its links
(with the locator); a link closes just before its transport and opens just after it,
so the locator of a router that is gone is the one its last link had, and a router's
return is said when its first link opens.

Data and ``now`` in, messages out: no Zenoh, no clock (the runtime's
:mod:`federation.runtime.routerwatch` feeds it).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

__all__ = ["Note", "RouterWatch"]


@dataclass(frozen=True)
class Note:
    """A line to log: ``level`` (logging's) and ``text``."""

    level: int
    text: str


@dataclass
class RouterWatch:
    """The routers of one session: which are up, at which locators, since when none."""

    who: str
    """Whose session (an agent's address, a host's agents), for the messages."""
    _routers: set[str] = field(default_factory=set)  # zids of the routers up
    _locators: dict[str, str] = field(default_factory=dict)  # zid -> its last link's
    _pending: set[str] = field(default_factory=set)  # routers back, no link seen yet
    _lost_at: float | None = None  # when the last router went (None: one is up)

    def transport(self, zid: str, is_router: bool, up: bool, now: float) -> Note | None:
        """A transport to ``zid`` opened (``up``) or closed."""
        if not is_router:
            self._locators.pop(zid, None)
            return None
        if up:
            self._routers.add(zid)
            if self._lost_at is not None:
                if zid in self._locators:  # its link's event came first
                    return self._back(self._locators[zid], now)
                self._pending.add(zid)  # said when its link opens, with the locator
            return None
        if zid not in self._routers:
            return None
        self._routers.discard(zid)
        self._pending.discard(zid)
        where = self._locators.pop(zid, f"zid {zid}")
        if self._routers:
            return Note(logging.WARNING, f"{self.who}: the router at {where} is gone")
        self._lost_at = now
        return Note(
            logging.WARNING,
            f"{self.who}: the router at {where} is gone: every other agent is out of reach "
            "(and shows as left) until a router is back",
        )

    def link(self, zid: str, locator: str, up: bool, now: float) -> Note | None:
        """A link to ``zid`` at ``locator`` opened (``up``) or closed."""
        # Kept whatever the order its transport's events come in (each listener runs on
        # a thread of its own): the transport's close then names the locator.
        self._locators[zid] = locator
        if not up or zid not in self._pending:
            return None
        self._pending.discard(zid)
        return self._back(locator, now)

    def _back(self, locator: str, now: float) -> Note:
        lost_at, self._lost_at = self._lost_at, None
        after = "" if lost_at is None else f" after {now - lost_at:.1f} s without one"
        return Note(logging.INFO, f"{self.who}: the router at {locator} is back{after}")

"""One Zenoh subscriber per key expression, shared by the agents of one session.

Agents hosted in one process on one session (``fedlab bench scale``, a lab's
gateway process running several virtual agents) all subscribe to the same
leader's pose. Zenoh would run one Python callback per subscriber per sample,
each taking the interpreter lock afresh (about 40 us each, measured with 16
agents in a process); a shared subscriber takes it once and calls every agent's
handler in turn (a few us each).
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

__all__ = ["Fanout"]

log = logging.getLogger("fedlab.fanout")

Handler = Callable[[zenoh.Sample], None]


class _Subscription:
    """What ``Fanout.subscribe`` returns: ``undeclare()`` removes the handler."""

    def __init__(self, fanout: Fanout, key: str, handler: Handler):
        self._fanout, self._key, self._handler = fanout, key, handler

    def undeclare(self) -> None:
        self._fanout._remove(self._key, self._handler)


class Fanout:
    def __init__(self, session: zenoh.Session):
        self.session = session
        self._lock = threading.Lock()
        self._handlers: dict[str, tuple[Handler, ...]] = {}
        self._subscribers: dict[str, Any] = {}

    def subscribe(self, key: str, handler: Handler) -> _Subscription:
        """Call ``handler`` with every sample on ``key``; the first one declares the
        Zenoh subscriber, the last one's ``undeclare()`` undeclares it."""
        with self._lock:
            self._handlers[key] = (*self._handlers.get(key, ()), handler)
            if key not in self._subscribers:
                deliver = functools.partial(self._deliver, key)
                self._subscribers[key] = self.session.declare_subscriber(
                    key, zenoh.handlers.Callback(deliver, indirect=False)
                )
        return _Subscription(self, key, handler)

    def _deliver(self, key: str, sample: zenoh.Sample) -> None:
        for handler in self._handlers.get(key, ()):  # a tuple: replaced, never mutated
            try:
                handler(sample)
            except Exception:  # handlers do not raise; one that does must not stop the rest
                log.exception("handler for %s failed", key)

    def _remove(self, key: str, handler: Handler) -> None:
        with self._lock:
            remaining = tuple(h for h in self._handlers.get(key, ()) if h is not handler)
            self._handlers[key] = remaining
            if remaining:
                return
            del self._handlers[key]
            subscriber = self._subscribers.pop(key, None)
        if subscriber is not None:
            try:
                subscriber.undeclare()
            except Exception as error:  # the session closed first
                log.debug("undeclare failed: %s", error)

"""One Zenoh subscriber per key expression, shared by the agents of one session.

Agents hosted in one process on one session (``fedlab bench scale``, a lab's
gateway process running several virtual agents) all subscribe to the same
leader's pose. Zenoh would run one Python callback per subscriber per sample,
each taking the interpreter lock afresh (about 40 us each, measured with 16
agents in a process); a shared subscriber takes it once and calls every agent's
handler in turn (a few us each). Each handler gets the sample as a :class:`Received`,
which converts each part (key, payload, source id, the decoded pose and its
reference stamp) once, whatever the number of agents that read it, and carries the
host's monotonic time at which the sample reached the process (``arrived``): each
agent's arrival time is that one, not the moment its turn among the co-hosted
agents came (the link watch measures the network, not the order of handlers).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from federation.core import wire

__all__ = ["Fanout", "Received"]

log = logging.getLogger("fedlab.fanout")

_UNSET: Any = object()


class Received:
    """One Zenoh sample as the agents of a process read it: each part is converted on
    first use and kept, so that N co-hosted agents decode a sample once, not N times.
    ``sample`` is the Zenoh sample itself (valid only during the callback);
    ``arrived`` the host's monotonic time when it reached the process."""

    __slots__ = ("_payload", "_pose", "_source", "_stamp", "arrived", "key", "sample", "size")

    def __init__(self, sample: zenoh.Sample):
        self.arrived = time.monotonic()
        self.sample = sample
        self.key = str(sample.key_expr)
        self.size = len(sample.payload)  # bytes, before anything is copied
        self._payload: bytes | None = None
        self._source: Any = _UNSET
        self._pose: Any = _UNSET
        self._stamp: Any = _UNSET

    def payload(self) -> bytes:
        if self._payload is None:
            self._payload = self.sample.payload.to_bytes()
        return self._payload

    def source(self) -> str | None:
        """The publishing session's id from the source info (None without one)."""
        if self._source is _UNSET:
            info = self.sample.source_info
            self._source = None if info is None else str(info.source_id.zid)
        source: str | None = self._source
        return source

    def pose(self) -> wire.PoseSample:
        """The payload as a pose sample (:class:`wire.DecodeError` if it is not one)."""
        if self._pose is _UNSET:
            self._pose = _decoded(wire.decode_pose, self.payload())
        return _value(self._pose)  # type: ignore[no-any-return]

    def stamp(self) -> wire.RefStamp | None:
        """The attachment as a reference stamp, None without one
        (:class:`wire.DecodeError` if it is not one)."""
        if self._stamp is _UNSET:
            attachment = self.sample.attachment
            self._stamp = (
                None if attachment is None else _decoded(wire.decode_stamp, attachment.to_bytes())
            )
        return _value(self._stamp)  # type: ignore[no-any-return]


def _decoded(decode: Callable[[bytes], Any], data: bytes) -> Any:
    """``decode(data)``, or the :class:`wire.DecodeError` it raised, kept to raise again
    for each agent that reads it (each counts the malformed sample)."""
    try:
        return decode(data)
    except wire.DecodeError as error:
        return error


def _value(kept: Any) -> Any:
    if isinstance(kept, wire.DecodeError):
        raise kept
    return kept


Handler = Callable[[Received], None]


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
        try:
            received = Received(sample)
        except Exception:  # a sample Zenoh could not describe: nothing to hand on
            log.exception("sample on %s unreadable", key)
            return
        for handler in self._handlers.get(key, ()):  # a tuple: replaced, never mutated
            try:
                handler(received)
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

"""Log when a session loses its router and when a router is back
(:class:`federation.core.routerwatch.RouterWatch` on Zenoh's transport and link
events)."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import zenoh

from federation.core.routerwatch import Note, RouterWatch

__all__ = ["watch_routers"]

log = logging.getLogger("fedlab.session")


def watch_routers(session: zenoh.Session, who: str) -> list[Any]:
    """Listeners on ``session`` that log its router going and coming back, naming
    ``who``; undeclare them (``undeclare()``) before the session closes. The routers
    up now are known at once (history): their return is not announced."""
    watch = RouterWatch(who)
    lock = threading.Lock()  # Zenoh calls each listener on a thread of its own

    def said(note: Note | None) -> None:
        if note is not None:
            log.log(note.level, "%s", note.text)

    def on_transport(event: zenoh.TransportEvent) -> None:
        try:
            transport, up = event.transport, event.kind == zenoh.SampleKind.PUT
            is_router = transport.whatami == zenoh.WhatAmI.ROUTER
            with lock:
                note = watch.transport(str(transport.zid), is_router, up, time.monotonic())
            said(note)
        except Exception:  # a Zenoh callback never raises
            log.exception("transport event %r failed", event)

    def on_link(event: zenoh.LinkEvent) -> None:
        try:
            link, up = event.link, event.kind == zenoh.SampleKind.PUT
            with lock:
                note = watch.link(str(link.zid), link.dst, up, time.monotonic())
            said(note)
        except Exception:
            log.exception("link event %r failed", event)

    # Transports first: the history's links then find their routers known.
    info = session.info
    return [
        info.declare_transport_events_listener(on_transport, history=True),
        info.declare_link_events_listener(on_link, history=True),
    ]

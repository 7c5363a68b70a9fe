"""One name, one process: how an agent (and the UDP bridge, for its legacy agent) makes
sure no other process runs under its ``lab/name``.

At start, :func:`name_alive` asks liveliness whether the name is already present (the
caller refuses to start: :class:`NameTaken`). Two processes that start under one name
within the same moment both pass that check, neither having declared the name yet. So
each looks again :data:`NAME_CHECKS_AFTER` after start with :func:`look_for_others`: a
sync query to its own sync key, to every queryable there, counting the sessions that
answer. Any session but its own means a clash; the caller holds for good, since which
of the two is genuine cannot be told in-band. A sync query, not a liveliness lookup: a
session that watches liveliness (every agent does) is answered one token per name,
however many sessions hold it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import zenoh

from federation.core import wire

__all__ = [
    "NAME_CHECKS_AFTER",
    "NameTaken",
    "clash_message",
    "look_again",
    "look_for_others",
    "name_alive",
]

log = logging.getLogger("fedlab.names")

NAME_CHECKS_AFTER = (2.0, 10.0)
"""s after start: the name is looked up again, for a second process that started under
it at the same time (both passed the check before either had declared it); the later
look finds one that declared it more slowly (the last agents of a large host)."""


class NameTaken(ValueError):
    """Another agent already uses this lab/name in the federation."""


def name_alive(session: zenoh.Session, token_key: str, timeout: float = 1.0) -> bool:
    """Whether a liveliness token is present on ``token_key`` (an agent's key)."""
    replies = session.liveliness().get(token_key, timeout=timeout)
    return any(reply.ok is not None for reply in replies)


def look_for_others(
    session: zenoh.Session,
    sync_key: str,
    payload: bytes,
    on_clash: Callable[[list[str]], None],
    timeout: float = 1.0,
) -> None:
    """Send ``payload`` (a sync request) to every queryable on ``sync_key``; once the
    query ends, call ``on_clash`` with the sorted ids of every session that answered
    (this one's included, if it answered) when a session other than this one did.
    Asynchronous: the replies come on Zenoh's threads. Raises what Zenoh raises when
    the query cannot be sent (the caller tries again)."""
    own = str(session.zid())
    repliers: set[str] = set()

    def replied(reply: Any) -> None:
        replier = reply.replier_id
        if reply.ok is not None and replier is not None:
            repliers.add(str(replier.zid))

    def done() -> None:
        if repliers - {own}:
            on_clash(sorted(repliers))

    session.get(
        sync_key,
        zenoh.handlers.Callback(replied, done, indirect=False),
        payload=payload,
        target=zenoh.QueryTarget.ALL,  # every queryable on the key, not the best
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout,
    )


def look_again(
    checks: list[float],
    host: float,
    session: zenoh.Session,
    sync_key: str,
    now: Callable[[], float],
    on_clash: Callable[[list[str]], None],
) -> None:
    """The look due at host monotonic ``host``, if any (a sync request stamped with the
    clock ``now`` reads): ``checks`` are the times of the looks still to make (the first
    is taken off when made); a look that cannot be sent is tried again a first look's
    delay later. See :func:`look_for_others`."""
    if not checks or host < checks[0]:
        return
    checks.pop(0)
    try:
        look_for_others(session, sync_key, wire.encode_request(now()), on_clash)
    except Exception as error:  # the session closing, or Zenoh refusing the query
        log.warning("looking again at who answers %s failed: %s", sync_key, error)
        checks.insert(0, host + NAME_CHECKS_AFTER[0])


def clash_message(who: str, federation: str, sessions: list[str]) -> str:
    """What a name clash is said as (logs, status, the run's events)."""
    return (
        f"{len(sessions)} processes answer for {who} in federation {federation} "
        f"(sessions {', '.join(sessions)})"
    )

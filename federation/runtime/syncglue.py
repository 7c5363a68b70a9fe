"""The Zenoh side of the sync exchange, written once for all who query a clock: an
agent's sync links, ctl's look at the reference clock, the UDP bridge and the ROS 2
bridge. The exchange itself (the paper's three timestamps and the estimate) is pure:
:mod:`federation.core.sync`.

- :class:`SyncQuerier` sends requests to one agent's sync key: its querier is declared
  on first use (no consolidation: every reply counts; express: no batching) and each
  reply reaches ``on_answer`` on Zenoh's thread, its ``t3`` read on arrival.
- :class:`Answer` is a reply as it arrived, read once (each read of a zenoh reply's
  fields builds a new object): whether it is an error, its size before anything is
  copied, its replier's session id; the payload and attachment are copied on demand.
- :func:`serve_query` answers a query and releases it at once (the querier would wait
  for its timeout otherwise).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import zenoh

__all__ = ["Answer", "Served", "SyncQuerier", "serve_query"]

log = logging.getLogger("fedlab.sync")


class Answer:
    """One sync reply, arrived at own time ``t3`` (host monotonic ``host``)."""

    __slots__ = ("_sample", "host", "size", "source", "t3")

    def __init__(self, reply: zenoh.Reply, t3: float, host: float):
        self.t3, self.host = t3, host
        self._sample = reply.ok  # None: an error reply
        self.size = 0 if self._sample is None else len(self._sample.payload)
        replier = reply.replier_id
        self.source: str | None = None if replier is None else str(replier.zid)

    @property
    def ok(self) -> bool:
        """Whether it is a reply, not an error."""
        return self._sample is not None

    def payload(self) -> bytes:
        """Its payload, copied (check :attr:`size` first)."""
        assert self._sample is not None
        return self._sample.payload.to_bytes()

    def attachment(self) -> bytes | None:
        """Its attachment, copied (None without one)."""
        if self._sample is None:
            return None
        attachment = self._sample.attachment
        return None if attachment is None else attachment.to_bytes()


class SyncQuerier:
    """Sync requests to ``key`` on ``session``; each reply (or error reply) is handed to
    ``on_answer`` with the time ``read`` gives on arrival (own time, host monotonic).

    Parameters
    ----------
    timeout : float
        Seconds a request waits for its reply.
    """

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        timeout: float,
        read: Callable[[], tuple[float, float]],
        on_answer: Callable[[Answer], None],
    ):
        self.session, self.key, self.timeout = session, key, timeout
        self._read = read
        self._on_answer = on_answer
        self._querier: Any = None
        self._handler = zenoh.handlers.Callback(self._arrived, indirect=False)

    def request(self, payload: bytes) -> None:
        """Send one request (raises what Zenoh raises: a session closing, a refusal)."""
        if self._querier is None:
            self._querier = self.session.declare_querier(
                self.key,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=self.timeout,
                express=True,
            )
        self._querier.get(self._handler, payload=payload)

    def _arrived(self, reply: zenoh.Reply) -> None:
        t3, host = self._read()  # read on arrival: the paper's t3
        try:
            self._on_answer(Answer(reply, t3, host))
        except Exception:
            log.exception("sync reply from %s failed", self.key)

    @property
    def declared(self) -> Any:
        """The Zenoh querier, once a request declared it (None before)."""
        return self._querier

    def close(self) -> None:
        """Undeclare the querier (a new request declares it again)."""
        querier, self._querier = self._querier, None
        if querier is not None:
            try:
                querier.undeclare()
            except Exception as error:  # the session closed first
                log.debug("undeclaring the querier on %s: %s", self.key, error)


Served = tuple[bytes, bytes | None]
"""A reply's payload and attachment."""


def serve_query(query: zenoh.Query, answer: Callable[[Any], Served | None]) -> bool:
    """Reply to ``query`` with what ``answer`` makes of its payload (a zenoh payload or
    None: its size can be judged before anything is copied): a payload and an
    attachment, or None for no reply. The query is released at once, whatever happens.
    True if a reply was sent."""
    try:
        served = answer(query.payload)
        if served is None:
            return False
        query.reply(query.key_expr, served[0], attachment=served[1])
        return True
    except Exception:
        log.exception("sync query on %s failed", query.key_expr)
        return False
    finally:
        query.drop()  # type: ignore[no-untyped-call]  # release now, or the querier waits

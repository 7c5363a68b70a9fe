"""ctl's look at the reference clock: a burst of sync exchanges with the reference agent
(the paper's three timestamps, :mod:`federation.core.sync`) that gives the reference's
time now, for the instant a start, freeze or resume is announced for."""

from __future__ import annotations

import threading
import time
from typing import Any

from federation.core import keys
from federation.core.clockfilter import ClockFilter
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.clock import ExecClock
from federation.runtime.session import ConnectError
from federation.runtime.syncglue import Answer, SyncQuerier

__all__ = [
    "REFERENCE_BURST",
    "REFERENCE_SPACING",
    "REFERENCE_UNANSWERED",
    "reference_now",
    "reference_sync",
]

REFERENCE_UNANSWERED = 3
"""Sync queries in a row the reference may leave unanswered (1 s each) before ctl gives up."""
REFERENCE_BURST = 20
"""Sync exchanges ctl takes with the reference for an instant (the best one counts)."""
REFERENCE_SPACING = 0.02
"""s between the burst's requests: they are in flight together, so the burst takes
about its length times this plus one round trip, whatever the path's delay."""


def reference_now(session: Any, federation: str, reference: AgentId, clock: ExecClock) -> float:
    """The reference agent's clock now, from a burst of sync exchanges (best of
    :data:`REFERENCE_BURST`).

    Raises :class:`~federation.runtime.session.ConnectError` when it does not answer
    (:data:`REFERENCE_UNANSWERED` queries in a row: a few seconds, not twenty).
    """
    return reference_sync(session, federation, reference, clock)[0]


def reference_sync(
    session: Any, federation: str, reference: AgentId, clock: ExecClock
) -> tuple[float, float]:
    """:func:`reference_now`, and ctl's median one-way delay to the reference (s).

    One query at a time until the reference answers one (it is there and its route is
    up), then the rest of the burst :data:`REFERENCE_SPACING` apart without waiting for
    each answer: over a 40 ms path, 20 exchanges one after another took 2.1 s."""
    client = SyncClient(ClockFilter(), timeout=1.0)
    key = keys.agent_key(federation, reference, "sync")
    answered = threading.Condition()
    sent, heard, replies = [0], [0], [0]  # requests; answers of any kind; those taken

    def on_answer(answer: Answer) -> None:
        with answered:  # the client's requests and answers, one at a time
            heard[0] += 1
            if answer.ok and client.receive(answer.payload(), answer.t3) is not None:
                replies[0] += 1
            answered.notify_all()

    def request() -> None:
        with answered:
            payload = client.request(clock.now())
            sent[0] += 1
        querier.request(payload)

    querier = SyncQuerier(session, key, 1.0, clock.read, on_answer)
    try:
        for _ in range(REFERENCE_UNANSWERED):
            mark = heard[0]
            request()
            with answered:  # an answer, or an error reply, or 1 s
                answered.wait_for(lambda: heard[0] > mark, 1.0)  # noqa: B023 (waited on here)
                if replies[0]:
                    break
        if replies[0]:
            for _ in range(REFERENCE_BURST - 1):
                time.sleep(REFERENCE_SPACING)
                request()
            with answered:  # each request waits 1 s for its answer
                answered.wait_for(lambda: heard[0] >= sent[0], 1.0)
    finally:
        querier.close()
    with answered:
        t = clock.now()
        offset, delay = client.offset_at(t), client.delay
    if offset is None or delay is None:
        raise ConnectError(f"reference agent {reference} did not answer sync queries on {key}")
    return t + offset, delay

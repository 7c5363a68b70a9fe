"""What the TCP and UDP relays share: the running link's state and the queue that holds
each chunk or datagram until its delivery time.

The asyncio layer only moves bytes: per direction a queue ordered by delivery time,
drained by one timer (``loop.call_at``) armed for its head, with a fast path that
writes at once when nothing is queued and the item is already due.

A queue holding more than ``max_queue_mib`` stops reading its source until it is
half drained. Nothing is delivered before its time; timers fire late by the loop's
wake-up latency (see :mod:`federation.link.runner` for why the loop uses select).
"""

from __future__ import annotations

import abc
import asyncio
import heapq
import math
from collections.abc import Callable
from typing import Generic, TypeVar

from federation.link.model import LinkModel
from federation.link.stats import DirectionStats, LinkStats
from schemas.config import ConfigError
from schemas.link import LinkOptions, parse_endpoint

__all__ = ["EARLY", "MAX_SESSIONS", "Relay", "TimedQueue", "endpoint_error"]

EARLY = 1e-6
"""A queued item this close to due (s) is sent now rather than the timer re-armed."""

MAX_SESSIONS = 256
"""TCP connections or UDP clients at most: select(2) takes descriptors below 1024 only."""


class Relay:
    """Shared state of a running link: loop, model, counters, queue cap, and what to
    do every second (``every_second``, run by :func:`federation.link.runner.serve`)."""

    def __init__(self, options: LinkOptions, loop: asyncio.AbstractEventLoop, seed: int):
        self.options = options
        self.loop = loop
        self.model = LinkModel.from_options(options, seed=seed, start=loop.time())
        self.stats = LinkStats(options.proto, options.listen, options.to, seed, loop.time())
        self.limit = int(options.max_queue_mib * 2**20)
        self.listen = parse_endpoint(options.listen)
        self.target = parse_endpoint(options.to)
        self.every_second: list[Callable[[], None]] = []


def endpoint_error(field: str, endpoint: str, reason: str, error: OSError) -> ConfigError:
    """A ConfigError naming the option (quoted, as :mod:`schemas.link` does) and the endpoint."""
    return ConfigError(f"'{field}' {endpoint}: {reason}: {error}")


T = TypeVar("T")


class TimedQueue(abc.ABC, Generic[T]):
    """Items of one direction held until their delivery time, then passed to
    :meth:`deliver`; equal times leave in the order they came.

    Subclasses define :meth:`deliver` and :meth:`hold_source` (stop or resume reading
    the source), and may define :meth:`drained` (called when the queue empties).
    ``T`` is what a subclass needs besides the bytes to deliver them (a UDP session).
    """

    def __init__(self, relay: Relay, stats: DirectionStats):
        self.relay = relay
        self.loop = relay.loop
        self.stats = stats
        self.heap: list[tuple[float, int, T, bytes]] = []
        self.seq = 0
        self.queued = 0  # bytes in this queue (stats.queued_bytes may span several queues)
        self.timer: asyncio.TimerHandle | None = None
        self.timer_at = math.inf
        self.full = False

    def put(self, at: float, now: float, item: T, data: bytes) -> None:
        """Deliver ``data`` at ``at`` (read at ``now``): at once if due and nothing waits."""
        if not self.heap and at <= now + EARLY:
            self.deliver(item, data)
            return
        heapq.heappush(self.heap, (at, self.seq, item, data))
        self.seq += 1
        self.queued += len(data)
        self.stats.queue(len(data))
        if at < self.timer_at:
            if self.timer is not None:
                self.timer.cancel()
            self.timer = self.loop.call_at(at, self._flush)
            self.timer_at = at
        if self.queued > self.relay.limit and not self.full:
            self.full = True
            self.hold_source(True)

    def _flush(self) -> None:
        self.timer = None
        self.timer_at = math.inf
        heap = self.heap
        due = self.loop.time() + EARLY
        while heap and heap[0][0] <= due:
            _, _, item, data = heapq.heappop(heap)
            self.queued -= len(data)
            self.stats.queued_bytes -= len(data)
            self.deliver(item, data)
        if heap:
            self.timer_at = heap[0][0]
            self.timer = self.loop.call_at(self.timer_at, self._flush)
        else:
            self.drained()
        if self.full and self.queued <= self.relay.limit // 2:
            self.full = False
            self.hold_source(False)

    def clear(self) -> None:
        """Drop what is queued (counted as ``dropped``) and stop the timer."""
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
            self.timer_at = math.inf
        self.stats.dropped += len(self.heap)
        self.stats.queued_bytes -= self.queued
        self.queued = 0
        self.heap.clear()

    @abc.abstractmethod
    def deliver(self, item: T, data: bytes) -> None:
        """Write ``data`` out now."""

    @abc.abstractmethod
    def hold_source(self, hold: bool) -> None:
        """Stop (``True``) or resume (``False``) reading the source: the queue is over
        the cap, or back under half of it."""

    def drained(self) -> None:
        """The timer found the queue empty after delivering."""

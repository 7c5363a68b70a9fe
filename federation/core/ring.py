"""The last N floats of a stream, in one contiguous buffer.

An agent keeps the lateness of its last 2000 control ticks and reports their
order statistics each second (status ``loop``). In a deque, 2000 floats are 2000
objects strewn over the heap; reading them once a second, cold in the cache,
cost a co-hosted agent's status a few hundred microseconds. Here they
are 16 kB of one array, which numpy reads without a copy per value.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator

__all__ = ["FloatRing"]


class FloatRing:
    """The last ``size`` floats appended (``size`` at least 1)."""

    __slots__ = ("_buffer", "_count", "_next", "size")

    def __init__(self, size: int):
        if size < 1:
            raise ValueError(f"size must be at least 1 value, not {size!r}")
        self.size = size
        self._buffer = array("d", bytes(8 * size))
        self._next = 0  # where the next value goes
        self._count = 0

    def append(self, value: float) -> None:
        self._buffer[self._next] = value
        self._next = (self._next + 1) % self.size
        if self._count < self.size:
            self._count += 1

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[float]:
        """Oldest first."""
        start = (self._next - self._count) % self.size
        for k in range(self._count):
            yield self._buffer[(start + k) % self.size]

    def values(self) -> memoryview:
        """The values held, in no particular order (for order statistics): a read-only
        view of the buffer (format ``d``), whose contents the next append changes."""
        return memoryview(self._buffer).toreadonly()[: self._count]

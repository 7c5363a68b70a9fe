"""The emulated device in real time on a pseudo-terminal (``fedlab emulate-device``).

:func:`run_emulator` opens a pseudo-terminal, hands its slave path (``/dev/pts/N``) to
the caller and moves bytes between its master side and an
:class:`~agents.serial.emulator.EmulatedDevice`, waking for the host's bytes and the
device's next deadline. A host opens the slave side as it would open a real platform's
USB serial port. All the device's logic is in :mod:`agents.serial.emulator`; this
module only reads the clock and moves bytes.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from agents.serial.emulator import EmulatedDevice

__all__ = ["run_emulator"]

log = logging.getLogger("fedlab.emulate_device")

_TX_CAP = 1024  # bytes queued for a host that is not reading; newer frames are dropped


def run_emulator(
    device_factory: Callable[[float], EmulatedDevice],
    stop: threading.Event,
    *,
    ready: Callable[[str], None] | None = None,
    link: Path | None = None,
    duration: float | None = None,
) -> EmulatedDevice:
    """Serve a device on a new pseudo-terminal until ``stop`` is set or ``duration`` passes.

    ``device_factory(start)`` builds the device with its time origin; ``ready`` gets
    the slave path once the terminal is open; ``link`` becomes a symlink to it.
    Returns the device, for its counters.
    """
    master, slave = os.openpty()
    link_made = False
    try:
        tty.setraw(slave)  # 8-bit clean: no echo, no CR/LF translation, no line editing
        os.set_blocking(master, False)
        path = os.ttyname(slave)
        if link is not None:
            _link_to(link, path)
            link_made = True
        if ready is not None:
            ready(path)
        start = time.monotonic()
        device = device_factory(start)
        end = math.inf if duration is None else start + duration
        tx_dropped = _serve(master, device, stop, end)
        log.info("device stopped at t=%.3f s; %d bytes dropped unread", device.t, tx_dropped)
        return device
    finally:
        os.close(master)
        os.close(slave)
        if link_made and link is not None:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()


def _link_to(link: Path, path: str) -> None:
    """Make ``link`` a symlink to ``path`` in one step: made beside it, then renamed over
    it, so a link left by an earlier run is replaced and is never missing meanwhile."""
    tmp = link.with_name(f".{link.name}.{os.getpid()}")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    tmp.symlink_to(path)
    tmp.replace(link)


def _serve(master: int, device: EmulatedDevice, stop: threading.Event, end: float) -> int:
    """Move bytes between the terminal's ``master`` side and ``device`` until ``stop`` is
    set or the monotonic clock reaches ``end``, waking for the host's bytes, the device's
    next deadline, and at least every 10 ms to see ``stop``. Returns the bytes dropped
    for a host that was not reading."""
    outbox = _Outbox()
    while not stop.is_set():
        now = time.monotonic()
        if now >= end:
            break
        wait = min(device.next_deadline(), end) - now
        readable, _, _ = select.select([master], [], [], min(max(wait, 0.0), 0.01))
        now = time.monotonic()
        if readable:
            _read_host(master, device, now)
        outbox.add(device.poll(now))
        outbox.flush(master)
    return outbox.dropped


def _read_host(master: int, device: EmulatedDevice, now: float) -> None:
    """The host's bytes waiting on ``master``, to ``device`` (none: nothing)."""
    try:
        data = os.read(master, 4096)
    except (BlockingIOError, InterruptedError):
        data = b""
    if data:
        device.receive(data, now)


class _Outbox:
    """The device's bytes not yet written to the host: at most ``_TX_CAP``; frames that
    would overflow it are dropped (counted in ``dropped``), so a host that is not
    reading costs bounded memory, and gets the oldest frames first once it reads."""

    def __init__(self) -> None:
        self.tx = bytearray()
        self.dropped = 0

    def add(self, out: bytes) -> None:
        if out:
            if len(self.tx) + len(out) <= _TX_CAP:
                self.tx += out
            else:
                self.dropped += len(out)

    def flush(self, master: int) -> None:
        """Write what the terminal takes now (non-blocking); keep the rest."""
        if self.tx:
            with contextlib.suppress(BlockingIOError):
                del self.tx[: os.write(master, self.tx)]

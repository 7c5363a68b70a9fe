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
            tmp = link.with_name(f".{link.name}.{os.getpid()}")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(path)
            tmp.replace(link)
            link_made = True
        if ready is not None:
            ready(path)
        start = time.monotonic()
        device = device_factory(start)
        end = math.inf if duration is None else start + duration
        tx = bytearray()
        tx_dropped = 0
        while not stop.is_set():
            now = time.monotonic()
            if now >= end:
                break
            wait = min(device.next_deadline(), end) - now
            readable, _, _ = select.select([master], [], [], min(max(wait, 0.0), 0.01))
            now = time.monotonic()
            if readable:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                if data:
                    device.receive(data, now)
            out = device.poll(now)
            if out:
                if len(tx) + len(out) <= _TX_CAP:
                    tx += out
                else:
                    tx_dropped += len(out)
            if tx:
                with contextlib.suppress(BlockingIOError):
                    del tx[: os.write(master, tx)]
        log.info("device stopped at t=%.3f s; %d bytes dropped unread", device.t, tx_dropped)
        return device
    finally:
        os.close(master)
        os.close(slave)
        if link_made and link is not None:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()

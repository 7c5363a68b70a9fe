"""The packet stage on a TUN device: reads IP packets the kernel routes into the
device, lets :class:`federation.link.packet.PacketStage` decide their fate and
writes each back at its delivery time, for the kernel to forward on.

The device is made beforehand (``ip tuntap add dev NAME mode tun``) with policy
routes sending the traffic between the two networks into it (the testbed,
:mod:`federation.testbed`, does this in its WAN namespace); this loop only
attaches to it. Linux only (``/dev/net/tun``), and needs CAP_NET_ADMIN.

Signals: SIGUSR1 cuts the path (every packet dropped), SIGUSR2 restores it,
SIGTERM or SIGINT stops. The counters are written to ``stats_json`` every second
and at exit, with the host monotonic times of the cuts.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import select
import signal
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from federation.link.packet import PacketStage

__all__ = ["open_tun", "run_stage"]

log = logging.getLogger("fedlab.link.packet")

_TUNSETIFF = 0x400454CA
_IFF_TUN = 0x0001
_IFF_NO_PI = 0x1000
_READ_BURST = 256  # packets read per wakeup at most, so writes are not starved


def open_tun(name: str) -> int:
    """A non-blocking descriptor on TUN device ``name`` (no packet information
    header: each read is one IP packet). OSError says why it cannot be opened."""
    if len(name.encode()) > 15:
        raise ValueError(f"TUN device name {name!r} longer than 15 bytes")
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    try:
        fcntl.ioctl(fd, _TUNSETIFF, struct.pack("16sH", name.encode(), _IFF_TUN | _IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


def run_stage(
    stage: PacketStage,
    device: str,
    *,
    duration: float | None = None,
    stats_json: Path | None = None,
    ready: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the stage on TUN ``device`` until SIGTERM/SIGINT or ``duration`` seconds;
    returns the final counters."""
    fd = open_tun(device)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    state = {"stop": False}
    cuts: list[dict[str, Any]] = []

    def on_signal(signum: int, _frame: object) -> None:
        if signum in (signal.SIGTERM, signal.SIGINT):
            state["stop"] = True
            return
        cut = signum == signal.SIGUSR1
        stage.set_cut(cut)
        cuts.append({"cut": cut, "host_monotonic": time.monotonic()})

    handled = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1, signal.SIGUSR2)
    previous = {sig: signal.signal(sig, on_signal) for sig in handled}
    old_wakeup = signal.set_wakeup_fd(wake_w)
    started = time.monotonic()
    deadline = None if duration is None else started + duration
    next_stats = started

    def snapshot() -> dict[str, Any]:
        return stage.snapshot() | {"cuts": list(cuts), "seconds": time.monotonic() - started}

    def write_stats() -> None:
        if stats_json is None:
            return
        tmp = stats_json.with_name(stats_json.name + ".tmp")
        try:
            tmp.write_text(json.dumps(snapshot(), indent=2) + "\n", encoding="utf-8")
            os.replace(tmp, stats_json)
        except OSError as error:
            log.warning("cannot write %s: %s", stats_json, error)

    if ready is not None:
        ready(device)
    try:
        while not state["stop"]:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            for packet in stage.due(now):
                try:
                    os.write(fd, packet)
                except OSError as error:  # e.g. no route for an ICMP reply
                    log.debug("write to %s failed: %s", device, error)
            if now >= next_stats:
                write_stats()
                next_stats = now + 1.0
            due = stage.next_due()
            timeout = min(next_stats - now, 1.0)
            if due is not None:
                timeout = min(timeout, max(0.0, due - now))
            if deadline is not None:
                timeout = min(timeout, max(0.0, deadline - now))
            readable, _, _ = select.select([fd, wake_r], [], [], timeout)
            if wake_r in readable:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 512)
            if fd in readable:
                for _ in range(_READ_BURST):
                    try:
                        packet = os.read(fd, 65536)
                    except BlockingIOError:
                        break
                    stage.offer(packet, time.monotonic())
    finally:
        signal.set_wakeup_fd(old_wakeup)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        os.close(wake_r)
        os.close(wake_w)
        os.close(fd)
        write_stats()
    return snapshot()

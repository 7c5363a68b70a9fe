"""The packet stage on a TUN device: reads IP packets the kernel routes into the
device, lets :class:`federation.link.packet.PacketStage` decide their fate and
writes each back at its delivery time, for the kernel to forward on.

The device is made beforehand (``ip tuntap add dev NAME mode tun``) with policy
routes sending the traffic between the two networks into it (the testbed,
:mod:`federation.testbed`, does this in its WAN namespace); this loop only
attaches to it. Linux only (``/dev/net/tun``), and needs CAP_NET_ADMIN.

Signals: SIGUSR1 cuts the path (every packet dropped), SIGUSR2 restores it,
SIGTERM or SIGINT stops. The counters are written to ``stats_json`` every second
(on a thread of their own, so a slow disk never delays a packet) and at exit, with
the host monotonic times of the cuts.
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
import threading
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


class _StatsWriter:
    """Writes the latest counters it is offered to ``path`` on a thread of its own,
    replacing the file whole so a reader never sees half of it. Offers made while a
    write is under way collapse into the newest."""

    def __init__(self, path: Path):
        self.path = path
        self._latest: dict[str, Any] | None = None
        self._closed = False
        self._ready = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="stage-stats", daemon=True)
        self._thread.start()

    def offer(self, snapshot: dict[str, Any]) -> None:
        with self._ready:
            self._latest = snapshot
            self._ready.notify()

    def close(self, final: dict[str, Any]) -> None:
        """Stop the thread and write ``final`` before returning."""
        with self._ready:
            self._closed = True
            self._latest = None
            self._ready.notify()
        self._thread.join(10.0)
        self._write(final)

    def _run(self) -> None:
        while True:
            with self._ready:
                while self._latest is None and not self._closed:
                    self._ready.wait()
                snapshot, self._latest = self._latest, None
            if snapshot is None:  # closed
                return
            self._write(snapshot)

    def _write(self, snapshot: dict[str, Any]) -> None:
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            tmp.write_text(json.dumps(snapshot, indent=2) + "\n", encoding="utf-8")
            os.replace(tmp, self.path)
        except OSError as error:
            log.warning("cannot write %s: %s", self.path, error)


class _StageLoop:
    """The stage on an open TUN descriptor: writes back what is due, offers what the
    kernel routes in, writes the counters every second; records the cuts it is
    signalled and stops when told or at its deadline."""

    def __init__(
        self,
        stage: PacketStage,
        fd: int,
        device: str,
        wake_r: int,
        stats_json: Path | None,
        duration: float | None,
    ):
        self.stage, self.fd, self.device, self.wake_r = stage, fd, device, wake_r
        self.writer = None if stats_json is None else _StatsWriter(stats_json)
        self.stop = False
        self.cuts: list[dict[str, Any]] = []
        self.started = time.monotonic()
        self.deadline = None if duration is None else self.started + duration
        self.next_stats = self.started

    def on_signal(self, signum: int, _frame: object) -> None:
        if signum in (signal.SIGTERM, signal.SIGINT):
            self.stop = True
            return
        cut = signum == signal.SIGUSR1
        self.stage.set_cut(cut)
        self.cuts.append({"cut": cut, "host_monotonic": time.monotonic()})

    def snapshot(self) -> dict[str, Any]:
        return self.stage.snapshot() | {
            "cuts": list(self.cuts),
            "seconds": time.monotonic() - self.started,
        }

    def write_stats(self) -> None:
        """Hand the counters to the writer (if any): the file is written on a thread of
        its own, so a slow disk never holds back a packet."""
        if self.writer is not None:
            self.writer.offer(self.snapshot())

    def run(self) -> None:
        while not self.stop:
            now = time.monotonic()
            if self.deadline is not None and now >= self.deadline:
                break
            self._write_due(now)
            if now >= self.next_stats:
                self.write_stats()
                self.next_stats = now + 1.0
            readable, _, _ = select.select([self.fd, self.wake_r], [], [], self._timeout(now))
            if self.wake_r in readable:  # a signal: drain the wake-up bytes
                with contextlib.suppress(BlockingIOError):
                    os.read(self.wake_r, 512)
            if self.fd in readable:
                self._read_burst()

    def _write_due(self, now: float) -> None:
        for packet in self.stage.due(now):
            try:
                os.write(self.fd, packet)
            except OSError as error:  # e.g. no route for an ICMP reply
                log.debug("write to %s failed: %s", self.device, error)

    def _timeout(self, now: float) -> float:
        """How long to wait for a packet: until the next delivery, stats or deadline,
        a second at most."""
        timeout = min(self.next_stats - now, 1.0)
        due = self.stage.next_due()
        if due is not None:
            timeout = min(timeout, max(0.0, due - now))
        if self.deadline is not None:
            timeout = min(timeout, max(0.0, self.deadline - now))
        return timeout

    def _read_burst(self) -> None:
        for _ in range(_READ_BURST):
            try:
                packet = os.read(self.fd, 65536)
            except BlockingIOError:
                break
            self.stage.offer(packet, time.monotonic())


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
    loop = _StageLoop(stage, fd, device, wake_r, stats_json, duration)
    handled = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1, signal.SIGUSR2)
    previous = {sig: signal.signal(sig, loop.on_signal) for sig in handled}
    old_wakeup = signal.set_wakeup_fd(wake_w)
    if ready is not None:
        ready(device)
    try:
        loop.run()
    finally:
        signal.set_wakeup_fd(old_wakeup)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        os.close(wake_r)
        os.close(wake_w)
        os.close(fd)
        if loop.writer is not None:
            loop.writer.close(loop.snapshot())
    return loop.snapshot()

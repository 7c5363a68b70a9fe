"""The insider ``kiruna/evil`` and what it sends, shared by the flood tests on loopback
(test_insider_flood.py, in-process sessions) and in the network testbed
(test_testbed_insider.py, where each side is a process in its lab's namespace).

As a script it is one of those processes, writing what it did as JSON::

    python insider.py flood   CONFIG OUT --sessions 10 --rounds 100 --rate 50
    python insider.py publish CONFIG OUT --seconds 4 --status-bytes 9472
    python insider.py watch   CONFIG OUT KEY

``flood`` opens one session after another (shared memory turned back on in each, an
attacker's choice), each sending ``--rounds`` rounds of a 1 MB sync query to the
leader and 1 MB puts on the insider's own pose and status keys, at ``--rate`` rounds a
second at most (on busy cores a session lasts longer; it never sends less).
``publish`` sends on its own keys at once: 1 MB poses at 50 Hz, poses of the largest
size the routers pass (:data:`federation.deploy.limits.SMALL_LIMIT`) at 500 Hz and
statuses of ``--status-bytes`` at 100 Hz, and writes when it sent each pose of the
largest size. ``watch`` (another lab's operator) subscribes to ``KEY`` and writes, per
key, what arrived: count, bytes, largest, and each arrival's time and size. Times are
``time.monotonic()``, one clock for every process on the host (network
namespaces share it). Each stops on SIGTERM and writes what it has.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from federation.deploy.limits import SMALL_LIMIT

__all__ = [
    "EVIL",
    "JUNK",
    "KNATTE_SYNC",
    "evil_config",
    "give_up_after",
    "rss_mb",
    "write_json",
]

JUNK = bytes(1_000_000)
EVIL = "fedlab/default/kiruna/evil"
KNATTE_SYNC = "fedlab/default/kiruna/knatte/sync"
QUERY_TIMEOUT = 0.2  # s: a dropped query's querier gets a timeout error after this


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` (MB, VmRSS from /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmRSS for pid {pid}")


def evil_config(path: Path | str) -> zenoh.Config:
    """``kiruna/evil``'s generated Zenoh config with shared memory turned back on, failing
    within 5 s if its router is unreachable."""
    conf = zenoh.Config.from_file(str(path))
    conf.insert_json5("transport/shared_memory/enabled", "true")
    return give_up_after(conf)


def give_up_after(conf: zenoh.Config, ms: int = 5000) -> zenoh.Config:
    """``conf`` failing within ``ms`` if its router is unreachable (an agent's waits)."""
    conf.insert_json5("connect/timeout_ms", str(ms))
    conf.insert_json5("connect/exit_on_failure", "true")
    return conf


def write_json(path: Path, data: dict[str, Any]) -> None:
    """``data`` to ``path`` at once (a reader never sees half a file)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data))
    tmp.replace(path)


class _Replies:
    """Replies to the flood's queries: answers and errors (a dropped query's timeout)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.ok = 0
        self.err = 0

    def ended(self) -> int:
        with self.lock:
            return self.ok + self.err

    def __call__(self, reply: zenoh.Reply) -> None:
        with self.lock:
            if reply.ok is not None:
                self.ok += 1
            else:
                self.err += 1


def _paced(
    rate: float,
    stop: threading.Event,
    step: Callable[[int], None],
    *,
    seconds: float = float("inf"),
    count: float = float("inf"),
) -> int:
    """Call ``step(i)`` on a schedule of ``rate`` Hz for ``seconds`` or ``count`` calls,
    whichever ends first (or until ``stop``); how many. Late calls catch up."""
    start = time.monotonic()
    i = 0
    while not stop.is_set() and i < count:
        now = time.monotonic()
        if now - start >= seconds:
            break
        step(i)
        i += 1
        stop.wait(max(0.0, start + i / rate - time.monotonic()))
    return i


def flood(config: Path, out: Path, sessions: int, rounds: int, rate: float) -> None:
    stop = _stop_on_sigterm()
    done: list[dict[str, Any]] = []
    for _ in range(sessions):
        if stop.is_set():
            break
        replies = _Replies()
        opened = time.monotonic()
        with zenoh.open(evil_config(config)) as session:

            def step(i: int, s: zenoh.Session = session, r: _Replies = replies) -> None:
                s.get(KNATTE_SYNC, r, payload=JUNK, timeout=QUERY_TIMEOUT)
                s.put(f"{EVIL}/pose", JUNK)
                s.put(f"{EVIL}/status", JUNK)

            started = time.monotonic()
            sent = _paced(rate, stop, step, count=rounds)
            ended = time.monotonic()
            # The last queries' timeouts: every query ends in a reply or an error.
            deadline = time.monotonic() + QUERY_TIMEOUT + 2.0
            while replies.ended() < sent and time.monotonic() < deadline:
                stop.wait(0.01)
        with replies.lock:
            done.append(
                {"opened": opened, "started": started, "ended": ended, "rounds": sent,
                 "replies": replies.ok, "errors": replies.err}
            )  # fmt: skip
        write_json(out, {"sessions": done, "finished": False})
    write_json(out, {"sessions": done, "finished": not stop.is_set()})


def publish(config: Path, out: Path, seconds: float, status_bytes: int) -> None:
    """At 500 Hz a pose of :data:`SMALL_LIMIT` bytes; every tenth tick a 1 MB pose
    (50 Hz) and every fifth a status of ``status_bytes`` (100 Hz); when each pose of
    :data:`SMALL_LIMIT` bytes was sent (what a router's downsampling can pass depends on
    their spacing)."""
    stop = _stop_on_sigterm()
    sent = {"pose_1mb": 0, "pose_max": 0, "status_max": 0}
    small, status = bytes(SMALL_LIMIT), bytes(status_bytes)
    pose_max_times: list[float] = []
    with zenoh.open(evil_config(config)) as session:
        pose = session.declare_publisher(f"{EVIL}/pose")
        stat = session.declare_publisher(f"{EVIL}/status")

        def step(i: int) -> None:
            pose.put(small)
            pose_max_times.append(time.monotonic())
            sent["pose_max"] += 1
            if i % 10 == 0:
                pose.put(JUNK)
                sent["pose_1mb"] += 1
            if i % 5 == 2:
                stat.put(status)
                sent["status_max"] += 1

        started = time.monotonic()
        ticks = _paced(500.0, stop, step, seconds=seconds)
        ended = time.monotonic()
        pose.undeclare()  # type: ignore[no-untyped-call]
        stat.undeclare()  # type: ignore[no-untyped-call]
    write_json(
        out,
        {"started": started, "ended": ended, "ticks": ticks, "sent": sent,
         "pose_max_times": pose_max_times},
    )  # fmt: skip


def watch(config: Path, out: Path, key: str) -> None:
    stop = _stop_on_sigterm()
    lock = threading.Lock()
    seen: dict[str, dict[str, Any]] = {}

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.monotonic()
        size = len(sample.payload) + (len(sample.attachment) if sample.attachment else 0)
        topic = str(sample.key_expr).rsplit("/", 1)[-1]
        with lock:
            entry = seen.setdefault(topic, {"count": 0, "bytes": 0, "largest": 0, "arrivals": []})
            entry["count"] += 1
            entry["bytes"] += size
            entry["largest"] = max(entry["largest"], size)
            if len(entry["arrivals"]) < 100_000:
                entry["arrivals"].append((now, size))

    def save(ready: bool) -> None:
        with lock:
            data = {"ready": ready, "at": time.monotonic(), "keys": json.loads(json.dumps(seen))}
        write_json(out, data)

    with zenoh.open(give_up_after(zenoh.Config.from_file(str(config)))) as session:
        sub = session.declare_subscriber(key, on_sample)
        save(True)
        while not stop.wait(0.5):
            save(True)
        sub.undeclare()  # type: ignore[no-untyped-call]
    save(True)


def _stop_on_sigterm() -> threading.Event:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return stop


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    for mode in ("flood", "publish", "watch"):
        p = sub.add_parser(mode)
        p.add_argument("config", type=Path, help="the Zenoh config of the identity to use")
        p.add_argument("out", type=Path, help="JSON file of what was done or seen")
        if mode == "flood":
            p.add_argument("--sessions", type=int, default=10)
            p.add_argument("--rounds", type=int, default=100, help="per session")
            p.add_argument("--rate", type=float, default=50.0, help="rounds a second")
        elif mode == "publish":
            p.add_argument("--seconds", type=float, default=4.0)
            p.add_argument("--status-bytes", type=int, required=True)
        else:
            p.add_argument("key", help="key expression to subscribe to")
    args = parser.parse_args(argv)
    if args.mode == "flood":
        flood(args.config, args.out, args.sessions, args.rounds, args.rate)
    elif args.mode == "publish":
        publish(args.config, args.out, args.seconds, args.status_bytes)
    else:
        watch(args.config, args.out, args.key)


if __name__ == "__main__":
    main()

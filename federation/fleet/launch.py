"""Start fedlab routers and agents as child processes and stop them by pid.

Used by ``fedlab demo`` and by the integration tests: every process started
here is tracked and stopped (SIGTERM, then SIGKILL after a grace period).
"""

from __future__ import annotations

import contextlib
import errno
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import IO

from federation.runtime.cpus import format_cpus, usable_cpus

__all__ = ["Fleet", "free_port", "free_ports", "wait_for"]

# Sets the process's cores, then becomes the command (same pid, threads inherit them).
_ON_CORES = (
    "import os, sys; "
    "os.sched_setaffinity(0, {int(c) for c in sys.argv[1].split(',')}); "
    "os.execvp(sys.argv[2], sys.argv[2:])"
)


PORTS = range(20000, 32768)
"""Where :func:`free_port` looks: below Linux's default ephemeral range (32768 to 60999),
so that no outgoing connection is given the port before its listener binds it."""
RESERVED_FOR = 120.0
"""s a port handed out by :func:`free_port` is kept from every other call on this host."""


def free_port(host: str = "127.0.0.1") -> int:
    """A port on ``host`` that nothing binds right now, for TCP nor UDP (a router listens
    on both), and that no call on this host (in any process) handed out in the last
    :data:`RESERVED_FOR` s. Parallel tests each start routers: two processes binding port
    0 one after the other may each be given the same port, and then one test's agents
    join the other's federation. Each port handed out is reserved by a file created
    with O_EXCL in a directory of this user's."""
    return free_ports(1, host).start


def free_ports(count: int, host: str = "127.0.0.1") -> range:
    """``count`` consecutive ports on ``host``, each as :func:`free_port` hands one out:
    unbound and reserved (for a command that takes the first and numbers the rest, as
    ``fedlab deploy generate --port P`` gives the labs' routers P, P + 1, ...)."""
    reserved = _reservations()
    starts = max(0, len(PORTS) - count + 1)  # the first ports a run of count can begin at
    first = random.randrange(starts) if starts else 0
    for i in range(starts):
        start = PORTS.start + (first + i) % starts
        ports = range(start, start + count)
        taken = []
        for port in ports:
            if not (_unbound(host, port) and _reserve(reserved, port)):
                break
            taken.append(port)
        else:
            return ports
        for port in taken:  # a run cut short: its reservations are given back
            _release(reserved, port)
    raise OSError(
        errno.EADDRINUSE,
        f"no {count} free consecutive port(s) on {host} in {PORTS.start}-{PORTS.stop - 1}",
    )


def _reservations() -> Path | None:
    """The directory of reserved ports (None if it cannot be made: nothing is reserved)."""
    folder = Path(tempfile.gettempdir()) / f"fedlab-ports-{os.getuid()}"
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        return None
    return folder


def _reserve(folder: Path | None, port: int) -> bool:
    """Reserve ``port``: False if another call holds it. A reservation older than
    :data:`RESERVED_FOR` is removed, and the port taken by a later call."""
    if folder is None:
        return True
    path = folder / str(port)
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        return True
    except FileExistsError:
        with contextlib.suppress(OSError):
            if time.time() - path.stat().st_mtime > RESERVED_FOR:
                path.unlink()
        return False
    except OSError:
        return True  # a directory that takes no file: the bind check alone


def _release(folder: Path | None, port: int) -> None:
    """Give back a reservation this call made."""
    if folder is not None:
        with contextlib.suppress(OSError):
            (folder / str(port)).unlink()


def _unbound(host: str, port: int) -> bool:
    """Whether ``port`` on ``host`` can be bound for TCP and for UDP now."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        with socket.socket(family, kind) as s:
            try:
                s.bind((host, port))
            except OSError:
                return False
    return True


class Fleet:
    """A set of ``fedlab`` child processes, each logging to ``log_dir/<name>.log``."""

    def __init__(self, log_dir: str | Path):
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: dict[str, IO[bytes]] = {}

    def start(self, name: str, args: Sequence[str]) -> subprocess.Popen[bytes]:
        """Run ``fedlab ARGS...`` with this interpreter; ``name`` must be unique while running."""
        return self.spawn(name, [sys.executable, "-m", "federation", *args])

    def spawn(
        self, name: str, argv: Sequence[str], cpus: Collection[int] | None = None
    ) -> subprocess.Popen[bytes]:
        """Run any command as a tracked child process; with ``cpus``, on those cores only
        (set before the command starts, so each of its threads runs on them: Linux; a
        core this process may not use is refused here, naming the process)."""
        if name in self.procs and self.procs[name].poll() is None:
            raise ValueError(f"process {name!r} is already running")
        if cpus is not None:
            usable = usable_cpus()
            if not cpus or not set(cpus) <= usable:
                raise ValueError(
                    f"process {name!r}: cores {format_cpus(cpus) or 'none'} are not among "
                    f"those it may use ({format_cpus(usable)})"
                )
            argv = [sys.executable, "-c", _ON_CORES, ",".join(map(str, sorted(cpus))), *argv]
        log = self.log_path(name).open("ab")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        proc = subprocess.Popen(
            list(argv),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )
        self.procs[name] = proc
        self._logs[name] = log
        return proc

    def log_path(self, name: str) -> Path:
        return self.log_dir / f"{name}.log"

    def stop(self, name: str, grace: float = 5.0, sig: int = signal.SIGTERM) -> int | None:
        """Stop one process by pid; returns its exit code."""
        proc = self.procs.get(name)
        if proc is None:
            return None
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, sig)
            try:
                proc.wait(grace)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(proc.pid, signal.SIGKILL)
                proc.wait(grace)
        log = self._logs.pop(name, None)
        if log is not None:
            log.close()
        return proc.returncode

    def kill(self, name: str) -> None:
        """Kill one process abruptly (SIGKILL), as a crash would."""
        self.stop(name, sig=signal.SIGKILL)

    def stop_all(self, last: Sequence[str] = ()) -> dict[str, int | None]:
        """Stop every process: agents before routers, so sessions close while their
        router is still up, and the processes named in ``last`` after both (e.g. the
        network path the routers close their sessions over)."""

        def group(name: str) -> int:  # agents and the rest, routers, then ``last``
            return 2 if name in last else int(name.startswith("router"))

        codes: dict[str, int | None] = {}
        for g in (0, 1, 2):
            codes |= self._stop_together([n for n in self.procs if group(n) == g])
        return codes

    def _stop_together(self, names: Sequence[str], grace: float = 5.0) -> dict[str, int | None]:
        """Signal every one of ``names`` (SIGTERM) at once, then wait for each, killed if
        it outlives ``grace``: they stop in the time the slowest takes, not the sum."""
        for name in names:
            if self.procs[name].poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.procs[name].pid, signal.SIGTERM)
        deadline = time.monotonic() + grace
        for name in names:
            proc = self.procs[name]
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(proc.pid, signal.SIGKILL)
                proc.wait(grace)
        return {name: self.stop(name) for name in names}  # each ended: its log closed

    def alive(self, name: str) -> bool:
        proc = self.procs.get(name)
        return proc is not None and proc.poll() is None

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()


def wait_for(predicate: Callable[[], object], timeout: float, interval: float = 0.1) -> bool:
    """Poll ``predicate()`` until true or ``timeout`` seconds pass (bounded)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())

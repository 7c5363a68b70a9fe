"""The testbed: real network stacks for two labs on this host, and everything
started in them stopped by pid and removed, even on failure.

``with Testbed(out, path=PacketOptions(delay=0.04)) as bed:`` builds the
namespaces of :mod:`federation.testbed.topology` (names prefixed per testbed, so
two testbeds never meet), starts the packet stage in the WAN namespace and
returns; ``bed.fedlab("rome", "router-rome", [...])`` runs a fedlab command in a
namespace, ``binds=[(DIR / "rome", ROOT)]`` with ``DIR/rome`` seen at ``ROOT`` by that
process alone, as a lab installs its generated folder (``Testbed(..., rome_hosts=2)``
adds a second host, ``rome2``, on Rome's
lab network); ``bed.cut()`` / ``bed.restore()`` cut the WAN; on exit every process
is stopped by pid (SIGTERM, then SIGKILL) and every namespace deleted. A
finalizer deletes the namespaces too if the object is dropped without ``close``.

Needs root (CAP_NET_ADMIN and CAP_SYS_ADMIN), ``ip`` (iproute2), ``nft``
(nftables) and ``/dev/net/tun``: :func:`missing` says which is absent.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from federation.fleet.launch import Fleet, wait_for
from federation.link.packet import PacketOptions
from federation.testbed.topology import (
    ADDR,
    TUN,
    build_commands,
    gateway_ruleset,
    lab_ruleset,
    roles,
)

__all__ = [
    "HOST_LOCK",
    "PREFIX",
    "Binds",
    "Testbed",
    "TestbedError",
    "leftover_namespaces",
    "missing",
    "probe_tcp",
    "raise_priority",
    "with_binds",
]

PREFIX = "fltb"
"""Every testbed namespace's name starts with this (then the pid and a counter)."""

_counter = itertools.count()
_STAGE = "stage"  # the packet stage's process name

HOST_LOCK = Path(tempfile.gettempdir()) / "fedlab-testbed.lock"
"""One testbed at a time on a host: a testbed's lab processes run ahead of everything
else (:data:`LAB_NICE`) to have the host's cores as their labs would, and two testbeds
at that priority take each other's cores. Beside parallel tests, three testbeds at once
held a follower's poses up to 199 ms on a clean 40 ms path (a safe hold) and starved
another test's agents into dropping 4.6 % of their poses as stale."""
HOST_LOCK_WAIT = 600.0
"""s a testbed waits for the one before it (ten of the suite's testbeds, end to end)."""

Binds = Sequence[tuple[str | Path, str | Path]]
"""Pairs of (folder, where a process sees it): see :func:`with_binds`."""


class TestbedError(RuntimeError):
    """The testbed could not be built or a command in it failed; says which."""

    __test__ = False  # not a pytest class


def missing() -> str | None:
    """Why a testbed cannot be built here (None: it can)."""
    if os.geteuid() != 0:
        return "needs root (network namespaces, nftables, TUN)"
    for tool in ("ip", "nft"):
        if shutil.which(tool) is None:
            package = "iproute2" if tool == "ip" else "nftables"
            return f"needs {tool!r} (Debian package {package})"
    if not os.path.exists("/dev/net/tun"):
        return "needs /dev/net/tun"
    probe = f"{PREFIX}probe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def leftover_namespaces(prefix: str = PREFIX) -> list[str]:
    """Namespaces whose name starts with ``prefix`` (a test checks none leaked)."""
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(prefix)]


def _delete_namespaces(names: Sequence[str]) -> None:
    for name in names:
        subprocess.run(["ip", "netns", "del", name], capture_output=True)


def _run(cmd: Sequence[str], stdin: str | None = None, timeout: float = 10.0) -> str:
    try:
        done = subprocess.run(
            list(cmd), input=stdin, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        raise TestbedError(f"{' '.join(cmd)}: no answer in {timeout:g} s") from None
    if done.returncode != 0:
        raise TestbedError(f"{' '.join(cmd)}: {done.stderr.strip() or done.returncode}")
    return done.stdout


def probe_tcp(namespace: str, host: str, port: int, timeout: float = 2.0) -> str:
    """Try a TCP connection from ``namespace`` to ``host:port``: "connected",
    "refused", "timeout" or the error's name."""
    code = (
        "import socket,sys\n"
        f"s=socket.socket(); s.settimeout({timeout!r})\n"
        "try:\n"
        f"    s.connect(({host!r},{port})); print('connected')\n"
        "except ConnectionRefusedError: print('refused')\n"
        "except TimeoutError: print('timeout')\n"
        "except OSError as e: print(type(e).__name__)\n"
    )
    out = _run(["ip", "netns", "exec", namespace, sys.executable, "-c", code], timeout=timeout + 10)
    return out.strip()


class Testbed:
    """Two labs' network stacks, the WAN between them and the processes in them.

    Parameters
    ----------
    out : Path
        Folder for the processes' logs and the stage's counters.
    path : PacketOptions
        The WAN towards Kiruna (forward); ``backward`` the way back (default: the same).
    kiruna_ports : sequence of str
        Ports Kiruna's firewall opens (``tcp/7447``, ``udp/7447``).
    sysctls : mapping
        Settings of every lab host's network stack (e.g. TCP's).
    seed : int
        The stage's random seed.
    rome_hosts : int
        Hosts on Rome's lab network (1 to 40): ``rome`` (192.0.2.10), then ``rome2``
        (192.0.2.11) ... on one switch behind the same gateway
        (:mod:`federation.testbed.topology`); run things on them by that role.
    """

    __test__ = False  # not a pytest class

    def __init__(
        self,
        out: str | Path,
        path: PacketOptions | None = None,
        backward: PacketOptions | None = None,
        *,
        kiruna_ports: Sequence[str] = ("tcp/7447",),
        sysctls: Mapping[str, str] | None = None,
        seed: int = 1,
        rome_hosts: int = 1,
    ):
        self.out = Path(out)
        self.path = path or PacketOptions()
        self.backward = backward
        self.kiruna_ports = tuple(kiruna_ports)
        self.sysctls = dict(sysctls or {})
        self.seed = seed
        self.rome_hosts = rome_hosts
        tag = f"{PREFIX}{os.getpid()}x{next(_counter)}"
        self.ns = {role: f"{tag}-{role}" for role in roles(rome_hosts)}
        self.fleet = Fleet(self.out / "logs")
        self.stats_path = self.out / "stage.json"
        self._made: list[str] = []
        self.stage_scheduling = "normal"  # set by start_stage: see raise_priority
        self._lock: Any = None  # the host's testbed lock (an open file) while it runs
        # Namespaces go even if close() is never called (the test crashed hard).
        self._finalizer = weakref.finalize(self, _delete_namespaces, self._made)

    # -- lifecycle -------------------------------------------------------------------
    def __enter__(self) -> Testbed:
        self._lock = _take_host_lock(HOST_LOCK, HOST_LOCK_WAIT)
        try:
            self.build()
            self.start_stage()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def build(self) -> None:
        """Namespaces, wires, addresses, routes, sysctls and firewalls."""
        for cmd in build_commands(self.ns, self.sysctls, self.rome_hosts):
            if cmd[:3] == ["ip", "netns", "add"]:
                self._made.append(cmd[3])
            _run(cmd)
        self.nft("rome-gw", gateway_ruleset())
        self.nft("kiruna", lab_ruleset(self.kiruna_ports))

    def start_stage(self, timeout: float = 30.0) -> None:
        """The packet stage on the WAN's TUN device, with :attr:`path`'s impairments
        (``timeout`` generous: on a loaded 2-core host Python alone took over 10 s).

        The stage runs at real-time priority (:func:`raise_priority`): it is the
        path, not a part of the federation, and a stage waiting for a core holds
        every packet in the TUN queue until it runs, which lengthens the path's
        delay past what :attr:`path` says. On a loaded 2-core host a stage at
        normal priority held packets up to 310 ms (40 ms configured) and the
        follower rightly held the platform on the late poses.
        :attr:`stage_scheduling` says which priority it got. Its counters
        (:attr:`stats_path`) are written off its forwarding loop
        (:mod:`federation.link.tun`), so a slow disk never holds a packet."""
        args = ["link", "--tun", TUN, "--forward-net", ADDR.kiruna_net, "--router", ADDR.wan_rome]
        args += ["--seed", str(self.seed), "--stats-json", str(self.stats_path)]
        args += _stage_flags(self.path, "")
        if self.backward is not None:
            args += _stage_flags(self.backward, "backward-")
        self.stats_path.unlink(missing_ok=True)
        stage = self.fedlab("wan", _STAGE, args)
        self.stage_scheduling = raise_priority(stage.pid)
        if not wait_for(self.stats_path.exists, timeout, 0.05):
            raise TestbedError(f"the packet stage did not start: {self.log(_STAGE)[-2000:]}")

    def close(self) -> None:
        """Stop every process by pid, then delete every namespace (idempotent).

        Agents first, then routers, then the packet stage: a router closing its
        session says so to the other lab's across the WAN, and with the stage gone
        first the close found no path and each router was killed after the 5 s grace.
        """
        try:
            self.fleet.stop_all(last=(_STAGE,))
        finally:
            _delete_namespaces(self._made)
            self._made.clear()
            if self._lock is not None:
                self._lock.close()  # releases the host's testbed lock
                self._lock = None

    # -- running things --------------------------------------------------------------
    def run(
        self,
        lab: str,
        *cmd: str,
        stdin: str | None = None,
        timeout: float = 10.0,
        binds: Binds = (),
    ) -> str:
        """Run a command in ``lab``'s namespace to completion (at most ``timeout`` s);
        its output. ``binds``: as :meth:`spawn`."""
        argv = ["ip", "netns", "exec", self.ns[lab], *with_binds(binds, cmd)]
        return _run(argv, stdin=stdin, timeout=timeout)

    def nft(self, lab: str, ruleset: str) -> None:
        self.run(lab, "nft", "-f", "-", stdin=ruleset)

    def spawn(
        self, lab: str, name: str, argv: Sequence[str], binds: Binds = (), nice: int | None = None
    ) -> subprocess.Popen[bytes]:
        """Start ``argv`` in ``lab``'s namespace as a tracked process (``ip netns exec``
        execs the command, so the pid is the command's own; ``binds``, pairs of
        (folder, where the process sees it), are mounted for it alone:
        :func:`with_binds`), at niceness
        :data:`LAB_NICE`: a lab's routers and agents have their host's cores to
        themselves, so on a host shared with other work (parallel tests) they run
        first, and what the testbed measures is the path, not the neighbours' load (at
        the default niceness, four test workers on two cores pause a leader between
        poses long enough to hold its follower on a clean path). Threads the process
        starts later inherit it. ``nice``: another niceness, for a process that is not
        the lab's (a load or an attacker that would run on a host of its own)."""
        proc = self.fleet.spawn(
            name, ["ip", "netns", "exec", self.ns[lab], *with_binds(binds, argv)]
        )
        with contextlib.suppress(OSError):  # not root: as it is
            os.setpriority(os.PRIO_PROCESS, proc.pid, LAB_NICE if nice is None else nice)
        return proc

    def fedlab(
        self, lab: str, name: str, args: Sequence[str], binds: Binds = ()
    ) -> subprocess.Popen[bytes]:
        """Start ``fedlab ARGS`` in ``lab``'s namespace (``binds``: as :meth:`spawn`)."""
        return self.spawn(lab, name, [sys.executable, "-m", "federation", *args], binds)

    def stop(self, name: str) -> int | None:
        return self.fleet.stop(name)

    def alive(self, name: str) -> bool:
        return self.fleet.alive(name)

    def log(self, name: str) -> str:
        path = self.fleet.log_path(name)
        return path.read_text(errors="replace") if path.exists() else ""

    # -- the WAN ---------------------------------------------------------------------
    def _signal_stage(self, sig: int) -> float:
        proc = self.fleet.procs.get(_STAGE)
        if proc is None or proc.poll() is not None:
            raise TestbedError("the packet stage is not running")
        at = time.monotonic()
        os.kill(proc.pid, sig)
        return at

    def cut(self) -> float:
        """Cut the WAN both ways; the host monotonic time of the cut (s)."""
        return self._signal_stage(signal.SIGUSR1)

    def restore(self) -> float:
        """End a cut; the host monotonic time (s)."""
        return self._signal_stage(signal.SIGUSR2)

    def stage_stats(self) -> dict[str, Any]:
        """The stage's counters as last written (every second)."""
        with contextlib.suppress(OSError, ValueError):
            data: dict[str, Any] = json.loads(self.stats_path.read_text())
            return data
        return {}

    def probe(self, lab: str, host: str, port: int, timeout: float = 2.0) -> str:
        """A TCP connection attempt from ``lab`` (see :func:`probe_tcp`)."""
        return probe_tcp(self.ns[lab], host, port, timeout)


STAGE_RT_PRIORITY = 1
"""SCHED_FIFO priority of the packet stage: the lowest real-time one, above every
ordinary process and below the kernel's own real-time threads."""
STAGE_NICE = -15
"""The stage's niceness where real-time scheduling is refused."""
LAB_NICE = -10
"""Niceness of a lab's processes in the testbed (routers, agents): ahead of anything at
the default 0, behind the packet stage (:data:`STAGE_NICE` or real time)."""


def _take_host_lock(path: Path, wait: float) -> Any:
    """The host's testbed lock at ``path`` (an open file holding an exclusive flock,
    released when closed or when this process ends), waiting up to ``wait`` s for the
    testbed holding it; else :class:`TestbedError` naming the holder's pid."""
    lock = path.open("a+")
    deadline = time.monotonic() + wait
    while True:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() >= deadline:
                lock.seek(0)
                holder = lock.read().strip() or "unknown"
                lock.close()
                raise TestbedError(
                    f"another testbed has held {path} for {wait:g} s (pid {holder}): "
                    "one testbed runs on a host at a time"
                ) from None
            time.sleep(0.1)
    lock.seek(0)
    lock.truncate()
    lock.write(f"{os.getpid()}\n")
    lock.flush()
    return lock


def raise_priority(pid: int) -> str:
    """Run process ``pid`` (and the threads it starts) first among this host's
    processes: SCHED_FIFO at :data:`STAGE_RT_PRIORITY`, or where that is refused
    (a container without CAP_SYS_NICE's real-time budget) niceness
    :data:`STAGE_NICE`. Says which: ``"fifo"``, ``"nice"`` or ``"normal"``.

    The stage is a select loop that sleeps between packets and uses a few percent
    of a core, so first place costs the rest of the host little; the kernel's
    real-time throttling (95 % of each second by default) bounds it if it spun."""
    with contextlib.suppress(OSError):
        os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(STAGE_RT_PRIORITY))
        return "fifo"
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, pid, STAGE_NICE)
        return "nice"
    return "normal"


def with_binds(binds: Binds, argv: Sequence[str]) -> list[str]:
    """``argv`` preceded by a shell that bind-mounts each (folder, target) of ``binds``
    and then execs it (the pid stays the command's own). Run under ``ip netns exec``,
    which gives the command a mount namespace of its own whose mounts never propagate
    back: the host and every other process keep seeing what they saw. A folder that
    cannot be mounted stops the command before it starts, saying which (exit code 97)."""
    if not binds:
        return list(argv)
    for source, target in binds:
        if not Path(source).is_dir() or not Path(target).is_dir():
            raise TestbedError(f"bind {source} on {target}: both must be existing folders")
    script = (
        'while [ "$1" != -- ]; do mount --bind "$1" "$2" '
        '|| { echo "testbed: cannot bind $1 on $2" >&2; exit 97; }; shift 2; done; '
        'shift; exec "$@"'
    )
    pairs = [str(p) for pair in binds for p in pair]
    return ["sh", "-c", script, "sh", *pairs, "--", *argv]


def _stage_flags(p: PacketOptions, prefix: str) -> list[str]:
    """``fedlab link --tun`` flags for one direction's options."""
    flags = [
        f"--{prefix}delay-ms", f"{p.delay * 1e3:g}",
        f"--{prefix}jitter-ms", f"{p.jitter * 1e3:g}",
        f"--{prefix}loss", f"{p.loss:g}",
    ]  # fmt: skip
    if prefix:
        return flags
    flags += ["--jitter-dist", p.jitter_dist, "--loss-burst", f"{p.loss_burst:g}"]
    if p.reorder:
        flags += ["--reorder", f"{p.reorder:g}", "--reorder-extra-ms", f"{p.reorder_extra * 1e3:g}"]
    if p.rate:
        flags += ["--rate-kbit", f"{p.rate * 8 / 1e3:g}", "--queue-kib", f"{p.queue / 1024:g}"]
    if p.mtu:
        flags += ["--mtu", str(p.mtu)]
    if not p.icmp:
        flags.append("--no-icmp")
    for at, length in p.cuts:
        flags += ["--cut", f"{at:g}:{length:g}"]
    return flags

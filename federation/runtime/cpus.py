"""Keeping a process to some of the host's cores (``fedlab router --cpus``,
``fedlab agent --cpus``).

On a small host that runs a lab's router beside its agents, a pose waits for a
core more than for anything else: the agents' Python runs in stretches of up to
a few milliseconds (a status, a pose handed to every co-hosted follower, the
recorder's write), and a router thread woken meanwhile on the same core waits
for the stretch to end (docs/scale.md "A late pose waits for a core"). A core of
the router's own, and the others for the agents, removes that wait. Linux only:
elsewhere pinning is refused with a clear error, never silently skipped.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

from schemas.config import ConfigError

__all__ = ["MAX_CPU", "format_cpus", "parse_cpus", "pin_process", "usable_cpus"]

MAX_CPU = 8191
"""The highest core number a list may name (Linux builds for at most 8192)."""


def parse_cpus(text: str) -> frozenset[int]:
    """The cores of a list such as ``0``, ``2-3`` or ``0,2-3`` (as ``taskset -c``
    takes them, without strides); ValueError naming the part that is not a core or
    a range of cores from 0 to :data:`MAX_CPU`."""
    cpus: set[int] = set()
    for part in text.split(","):
        bad = part.strip()
        where = repr(bad) if bad == text.strip() else f"{bad!r} in {text!r}"
        first, dash, last = bad.partition("-")
        bounds = [first, last] if dash else [first]
        if not all(b.isascii() and b.isdecimal() for b in bounds):
            raise ValueError(f"{where} is not a core or a range of cores (such as 0 or 2-3)")
        low, high = int(bounds[0]), int(bounds[-1])
        if high < low or high > MAX_CPU:
            raise ValueError(f"{where}: cores go from 0 to {MAX_CPU}, a range low-high")
        cpus.update(range(low, high + 1))
    return frozenset(cpus)


def format_cpus(cpus: Collection[int]) -> str:
    """``cpus`` as a list :func:`parse_cpus` reads (``0-2,5``)."""
    runs: list[list[int]] = []
    for cpu in sorted(set(cpus)):
        if runs and runs[-1][1] == cpu - 1:
            runs[-1][1] = cpu
        else:
            runs.append([cpu, cpu])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def usable_cpus(pid: int = 0) -> frozenset[int]:
    """The cores process ``pid`` (default: this one; its main thread) may run on;
    ConfigError where the platform cannot tell, OSError for a process gone."""
    if not hasattr(os, "sched_getaffinity"):
        raise ConfigError("cores: this platform cannot keep a process to some cores (Linux only)")
    return frozenset(os.sched_getaffinity(pid))


def pin_process(cpus: Collection[int], what: str) -> None:
    """Run this process, every thread it has and every thread it starts from now on,
    on ``cpus`` only. ConfigError naming ``what`` (the flag or field that asked) if
    one of them is not a core this process may use, or the platform cannot pin."""
    wanted = frozenset(cpus)
    allowed = usable_cpus()
    if not wanted:
        raise ConfigError(f"{what}: no core given")
    missing = wanted - allowed
    if missing:
        cores = "cores" if len(missing) > 1 else "core"
        raise ConfigError(
            f"{what}: {cores} {format_cpus(missing)} not among those this process may use "
            f"({format_cpus(allowed)})"
        )
    tasks = Path("/proc/self/task")
    if not tasks.is_dir():
        raise ConfigError(f"{what}: cannot list this process's threads to keep them to cores")
    # Threads already started (by an import) keep their own mask: each is set, until a
    # listing finds none new (one not yet set may have started another meanwhile).
    done: set[int] = set()
    while todo := {int(t.name) for t in tasks.iterdir()} - done:
        for tid in todo:
            try:
                os.sched_setaffinity(tid, wanted)
            except ProcessLookupError:  # the thread ended meanwhile
                pass
            except OSError as error:
                raise ConfigError(
                    f"{what}: cannot keep this process to {format_cpus(wanted)}: {error}"
                ) from None
        done |= todo

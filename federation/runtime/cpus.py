"""Keeping a process to some of the host's cores (``fedlab router --cpus``).

On a small host that runs a lab's router beside its agents, a pose waits for a
core more than for anything else: the agents' Python runs in stretches of up to
a few milliseconds (a status, a pose handed to every co-hosted follower, the
recorder's write), and a router thread woken meanwhile on the same core waits
for the stretch to end (issue 17, docs/scale.md "A late pose waits for a
core"). A core of the router's own removes that wait. Linux only: elsewhere
pinning is refused with a clear error, never silently skipped.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

from schemas.config import ConfigError

__all__ = ["format_cpus", "parse_cpus", "pin_process", "usable_cpus"]


def parse_cpus(text: str) -> frozenset[int]:
    """The cores of a list such as ``0``, ``2-3`` or ``0,2-3`` (as ``taskset -c``
    takes them); ValueError naming the part that is not a core or a range."""
    cpus: set[int] = set()
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        try:
            low = int(first)
            high = int(last) if dash else low
        except ValueError:
            bad = part.strip()
            raise ValueError(f"{bad!r} in {text!r} is not a core or a range of cores") from None
        if low < 0 or high < low:
            raise ValueError(f"{part.strip()!r} in {text!r}: cores count up from 0, low-high")
        cpus.update(range(low, high + 1))
    return frozenset(cpus)


def format_cpus(cpus: Collection[int]) -> str:
    """``cpus`` as a list :func:`parse_cpus` reads (``0-2,5``)."""
    runs: list[str] = []
    for cpu in sorted(cpus):
        if runs and runs[-1].split("-")[-1] == str(cpu - 1):
            runs[-1] = f"{runs[-1].split('-')[0]}-{cpu}"
        else:
            runs.append(str(cpu))
    return ",".join(runs)


def usable_cpus() -> frozenset[int]:
    """The cores this process may run on; ConfigError where the platform cannot tell."""
    if not hasattr(os, "sched_getaffinity"):
        raise ConfigError("cores: this platform cannot keep a process to some cores (Linux only)")
    return frozenset(os.sched_getaffinity(0))


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
        raise ConfigError(
            f"{what}: core {format_cpus(missing)} is not one this process may use "
            f"(it may use {format_cpus(allowed)})"
        )
    # Threads already started (by an import) keep their own mask: each is set too.
    tasks = Path("/proc/self/task")
    tids = [int(t.name) for t in tasks.iterdir()] if tasks.is_dir() else [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, wanted)
        except ProcessLookupError:  # the thread ended meanwhile
            continue
        except OSError as error:
            cores = format_cpus(wanted)
            raise ConfigError(f"{what}: cannot keep this process to {cores}: {error}") from None

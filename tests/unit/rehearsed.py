"""Rehearsals several unit tests judge: each seeded run flown once per test session.

The benchmark's rows (tests/unit/bench/test_bench_scenarios.py) and the rehearsal's own
claims (tests/unit/agents/test_rehearsal.py) judge the same seeded runs of
:mod:`agents.rehearsal`. A run is a pure function of its arguments, so the first test to
ask for one flies it and keeps its result in a folder every worker of the session shares
(the ``rehearsals`` fixture, tests/unit/conftest.py); a worker asking for a run another
is flying waits for it on the run's lock file, and then reads it.
"""

from __future__ import annotations

import fcntl
import hashlib
import inspect
import os
import pickle
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from agents import rehearsal

__all__ = ["Rehearsals"]


def _key(value: Any) -> Hashable:
    """A hashable stand-in for an argument: a validated model by its type and content."""
    if isinstance(value, BaseModel):
        return (type(value).__name__, value.model_dump_json())
    if isinstance(value, Hashable):
        return value
    raise TypeError(f"a rehearsal argument must be hashable or a pydantic model: {value!r}")


class Rehearsals:
    """:func:`agents.rehearsal.formation_run` and ``adaptive_run`` with their results kept
    by arguments in ``folder`` (one per test session). Results are shared: a test reads
    them, never changes them."""

    def __init__(self, folder: Path) -> None:
        self._folder = folder
        self._runs: dict[Hashable, Any] = {}

    def _once(self, run: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        bound = inspect.signature(run).bind(*args, **kwargs)
        bound.apply_defaults()  # the same run however its arguments were spelled
        key = (run.__name__, tuple((k, _key(v)) for k, v in bound.arguments.items()))
        if key in self._runs:
            return self._runs[key]
        name = hashlib.sha256(repr(key).encode()).hexdigest()[:32]
        path = self._folder / f"{name}.pickle"
        with open(self._folder / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            if path.exists():
                got = pickle.loads(path.read_bytes())
            else:
                got = run(*args, **kwargs)
                part = path.with_suffix(".part")
                part.write_bytes(pickle.dumps(got))
                os.replace(part, path)
        self._runs[key] = got
        return got

    def formation_run(self, *args: Any, **kwargs: Any) -> dict[str, Any]:
        got: dict[str, Any] = self._once(rehearsal.formation_run, *args, **kwargs)
        return got

    def adaptive_run(self, *args: Any, **kwargs: Any) -> dict[str, Any]:
        got: dict[str, Any] = self._once(rehearsal.adaptive_run, *args, **kwargs)
        return got

"""federation/testbed/deployment.py's ``start_run``: the ``fedlab ctl start`` it runs in
Kiruna's namespace, read from a stand-in testbed that records the command (no namespace)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import pytest

from federation.testbed import Testbed
from federation.testbed.bed import TestbedError
from federation.testbed.deployment import Deployment, start_run


class RecordingBed:
    """Records each ``fedlab`` command; each ends at once with ``code``."""

    def __init__(self, code: int = 0):
        self.code = code
        self.commands: list[tuple[str, str, list[str]]] = []

    def fedlab(self, lab: str, name: str, args: Sequence[str], binds: Any = ()) -> Any:
        self.commands.append((lab, name, list(args)))
        return subprocess.Popen([sys.executable, "-c", f"raise SystemExit({self.code})"])

    def log(self, name: str) -> str:
        return f"{name}'s log"


def started(tmp_path: Path, **kw: Any) -> list[str]:
    bed = RecordingBed()
    dep = Deployment(tmp_path / "generated", Path("/etc/fedlab"), tmp_path / "federation.toml")
    start_run(cast(Testbed, bed), dep, 30, **kw)
    ((lab, name, args),) = bed.commands
    assert (lab, name) == ("kiruna", "ctl")
    return args


def test_ctl_discovers_for_its_default_unless_told(tmp_path: Path) -> None:
    args = started(tmp_path, start_in=1)
    assert args[:6] == ["ctl", "start", "--duration", "30", "--in", "1"]
    assert "--discover" not in args
    assert args[-2:] == ["-c", "/etc/fedlab/operators/ctl.json5"]


def test_ctl_discovers_for_as_long_as_asked(tmp_path: Path) -> None:
    args = started(tmp_path, discover=0.5)
    assert args[args.index("--discover") + 1] == "0.5"


def test_a_start_that_fails_raises_with_its_log(tmp_path: Path) -> None:
    dep = Deployment(tmp_path, Path("/etc/fedlab"), tmp_path / "federation.toml")
    with pytest.raises(TestbedError, match="ctl start exited with 1\nctl's log"):
        start_run(cast(Testbed, RecordingBed(code=1)), dep, 30)

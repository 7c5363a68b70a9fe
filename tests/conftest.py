"""Fixtures for integration tests: real routers and agents as processes on loopback."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from federation.fleet.launch import Fleet


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[Fleet]:
    """Child processes, all stopped by pid at teardown; their logs are printed on failure."""
    f = Fleet(tmp_path / "logs")
    try:
        yield f
    finally:
        codes = f.stop_all()
        for name in codes:
            log = f.log_path(name)
            if log.exists():
                print(f"--- {name} (exit {codes[name]}) ---\n{log.read_text()[-3000:]}")

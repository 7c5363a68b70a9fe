"""Fixtures: real routers and agents as processes on loopback (integration tests), and a
real Zenoh session on loopback (unit tests that need one; closed after each)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from federation.fleet.launch import Fleet
from federation.runtime.runs import LEDGER_ENV


@pytest.fixture(autouse=True)
def promises_ledger(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Path:
    """Each test's recordings (and its child processes') promise disk space in a ledger of
    their own, not the host's: no test's budget depends on another's, or on a real run."""
    folder = tmp_path_factory.mktemp("promises")
    monkeypatch.setenv(LEDGER_ENV, str(folder))
    return folder


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


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as s:
        yield s

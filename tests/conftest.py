"""Fixtures: real routers and agents as processes on loopback (integration tests), and a
real Zenoh session on loopback (unit tests that need one; closed after each)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from federation.fleet.launch import Fleet
from federation.runtime import runs
from federation.runtime.agent import recordings
from federation.runtime.runs import LEDGER_ENV


@pytest.fixture(autouse=True)
def promises_ledger(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Path:
    """Each test's recordings (and its child processes') promise disk space in a ledger of
    their own, not the host's, and in a process-wide table of their own: no test's budget
    depends on another's, or on a real run. A test that abandons a recording as a killed
    process would (its promise never given back) leaves nothing to the next test run on
    the same worker."""
    folder = tmp_path_factory.mktemp("promises")
    monkeypatch.setenv(LEDGER_ENV, str(folder))
    fresh = runs._Promises()
    monkeypatch.setattr(runs, "PROMISES", fresh)
    monkeypatch.setattr(recordings, "PROMISES", fresh)
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


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """``-m timing`` (make test's second pass) imports only the test files that mark a
    test ``timing``: collecting every file to keep 16 tests took longer than some of them."""
    if config.getoption("markexpr") != "timing" or collection_path.suffix != ".py":
        return None
    if not collection_path.name.startswith("test_"):
        return None
    return "mark.timing" not in collection_path.read_text(encoding="utf-8")


# Test folders of pure computation (simulated time; no process, socket or pty, and no
# real clock): make test runs them at nice 5, beside the real processes.
COMPUTATION = ("unit/core/", "unit/report/", "unit/bench/", "unit/agents/")
REAL_TIME = ("unit/agents/test_serial_platform.py", "unit/agents/test_interface.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Marks ``computation`` the tests in :data:`COMPUTATION`'s folders (less
    :data:`REAL_TIME`'s files)."""
    root = Path(__file__).parent
    for item in items:
        where = item.path.relative_to(root).as_posix()
        if where.startswith(COMPUTATION) and not where.startswith(REAL_TIME):
            item.add_marker(pytest.mark.computation)

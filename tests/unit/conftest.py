"""Fixtures for the unit tests: the session's rehearsal runs (tests/unit/rehearsed.py)."""

from __future__ import annotations

import os

import pytest
from rehearsed import Rehearsals


@pytest.fixture(scope="session")
def rehearsals(tmp_path_factory: pytest.TempPathFactory) -> Rehearsals:
    """The session's rehearsal runs, each flown once. Under xdist, every worker's base
    folder is in the session's own (pytest-N/popen-gwK): the runs are kept there, beside
    them, for all the workers and for this session alone."""
    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if "PYTEST_XDIST_WORKER" in os.environ else base) / "rehearsals"
    folder.mkdir(exist_ok=True)
    return Rehearsals(folder)

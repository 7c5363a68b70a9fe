"""Fixtures of the integration tests: routers, links and agents as processes on loopback.

``labs`` gives the factories (tests/integration/loopback.py):
``labs.router(lab, listen=..., connect=...)``, ``labs.link(to, ...)``,
``labs.pair(link=...)`` (kiruna listening, rome dialling it, optionally through
``fedlab link``), ``labs.agent(who, at, ...)``, ``labs.leader(at, ...)`` and
``labs.follower(at, ...)``. Every process runs in the test's ``fleet``
(tests/conftest.py): stopped by pid at teardown, its log printed on failure.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from loopback import Labs

from federation.fleet.launch import Fleet


@pytest.fixture
def labs(fleet: Fleet, tmp_path: Path) -> Labs:
    """Factories of fedlab routers, links and agents in this test's fleet and folder."""
    return Labs(fleet, tmp_path)

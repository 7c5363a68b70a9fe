"""A real Zenoh session on loopback for the unit tests that need one (closed after each)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import zenoh


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as s:
        yield s

"""fedlab agent under an experiment's stand-in name: refused with why, so that no twin
flies without the role's rules kept (federation/core/standin.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.cli.agent import build_agent_config
from schemas.base import ConfigError

EXPERIMENT = """
name = "demo"
duration = 20
stand_in = { agent = "rome/twin", preset = "knatte" }

[[participants]]
agent = "kiruna/knatte"
role = "leader"

[[participants]]
agent = "rome/fnatte"
role = "follower"
follow = "kiruna/knatte"
"""


def test_the_stand_in_is_refused_with_why(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(EXPERIMENT, encoding="utf-8")
    with pytest.raises(ConfigError, match="rome/twin is the experiment's stand-in") as error:
        build_agent_config(None, path, {"lab": "rome", "name": "twin"})
    assert "followers of kiruna/knatte hold when it is lost" in str(error.value)
    # The participants still take their parts.
    follower = build_agent_config(None, path, {"lab": "rome", "name": "fnatte"})
    assert follower.follow == "kiruna/knatte"

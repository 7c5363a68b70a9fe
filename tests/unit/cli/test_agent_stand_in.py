"""fedlab agent under an experiment's stand-in name: a stand-in's config (a simulated twin
of the leader's preset, its reference the leader, every run under way joined), and what
a stand-in may not be."""

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


def test_the_stand_in_gets_a_twin_of_the_leaders_preset(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(EXPERIMENT, encoding="utf-8")
    twin = build_agent_config(None, path, {"lab": "rome", "name": "twin"})
    assert (twin.role, twin.platform, twin.reference, twin.follow) == (
        "stand-in", "knatte", "kiruna/knatte", None,
    )  # fmt: skip
    assert twin.wait_start and twin.rejoin_policy == "auto" and twin.run_duration == 20
    assert twin.experiment == path
    # The participants still take their parts.
    follower = build_agent_config(None, path, {"lab": "rome", "name": "fnatte"})
    assert follower.follow == "kiruna/knatte"


def test_a_stand_in_is_never_another_kind_of_platform(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(EXPERIMENT, encoding="utf-8")
    with pytest.raises(ConfigError, match="a stand-in is a simulated twin"):
        build_agent_config(None, path, {"lab": "rome", "name": "twin", "platform": "kinematic"})
    with pytest.raises(ConfigError, match="takes its part from its experiment"):
        build_agent_config(
            None, None, {"lab": "rome", "name": "twin", "role": "stand-in", "platform": "knatte"}
        )

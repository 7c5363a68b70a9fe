"""A follower under an experiment learns the preset its leader flies (its heading
filter's model of the leader: agents.flown); nothing where the leader flies no preset or
it follows another follower."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.cli.agent import build_agent_config
from schemas.base import ConfigError

EXPERIMENT = """
name = "chain"
duration = 20

[[participants]]
agent = "kiruna/knatte"
role = "leader"
platform = "{leader}"

[[participants]]
agent = "rome/pinocchio"
role = "follower"
platform = "pinocchio"
follow = "kiruna/knatte"

[[participants]]
agent = "rome/second"
role = "follower"
follow = "rome/pinocchio"
"""


def config(tmp_path: Path, leader: str, name: str) -> object:
    path = tmp_path / "chain.toml"
    path.write_text(EXPERIMENT.format(leader=leader), encoding="utf-8")
    return build_agent_config(None, path, {"lab": "rome", "name": name})


def test_a_follower_of_a_preset_leader_models_it_with_that_preset(tmp_path: Path) -> None:
    assert config(tmp_path, "knatte", "pinocchio").follow_preset == "knatte"  # type: ignore[attr-defined]
    # A follower of a follower: the agent it follows does not fly the maneuver.
    assert config(tmp_path, "knatte", "second").follow_preset is None  # type: ignore[attr-defined]
    # A kinematic leader flies its reference exactly: the maneuver itself is the model.
    assert config(tmp_path, "kinematic", "pinocchio").follow_preset is None  # type: ignore[attr-defined]


def test_a_follow_preset_that_is_no_preset_fails_at_load_naming_the_field() -> None:
    base = {"lab": "rome", "name": "f", "role": "follower", "follow": "kiruna/knatte"}
    with pytest.raises(ConfigError, match="follow_preset"):
        build_agent_config(None, None, {**base, "follow_preset": "kinematic"})
    with pytest.raises(ConfigError, match="follow_preset"):
        build_agent_config(None, None, {**base, "follow_preset": "no-such-preset"})
    assert build_agent_config(None, None, {**base, "follow_preset": "pinocchio"}).follow_preset == (
        "pinocchio"
    )


def test_a_leader_platform_file_missing_here_leaves_the_maneuver_and_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    missing = tmp_path / "elsewhere" / "leader.toml"  # only the leader's host has it
    assert config(tmp_path, str(missing), "pinocchio").follow_preset is None  # type: ignore[attr-defined]
    assert "does not load here" in caplog.text and str(missing) in caplog.text

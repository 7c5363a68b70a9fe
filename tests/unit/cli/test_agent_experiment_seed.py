"""A participant's ``seed`` in an experiment sets its simulated platform's noise in every
kind of experiment, plain attitude tracking as much as one with a scenario part; without
one, the agent's default stands."""

from __future__ import annotations

from pathlib import Path

from federation.cli.agent import build_agent_config

EXPERIMENT = """
name = "seeded"
duration = 20
{kind}
[[participants]]
agent = "kiruna/knatte"
role = "leader"
platform = "knatte"
seed = 4

[[participants]]
agent = "rome/pinocchio"
role = "follower"
platform = "pinocchio"
follow = "kiruna/knatte"
{adaptive}
"""


def seed(tmp_path: Path, lab: str, name: str, adaptive: bool = False) -> object:
    path = tmp_path / "seeded.toml"
    path.write_text(
        EXPERIMENT.format(
            kind="", adaptive="adaptive_gains = true\nseed = 7\n" if adaptive else ""
        ),
        encoding="utf-8",
    )
    return build_agent_config(None, path, {"lab": lab, "name": name}).seed


def test_a_participants_seed_holds_in_plain_attitude_tracking(tmp_path: Path) -> None:
    assert seed(tmp_path, "kiruna", "knatte") == 4  # the leader: no scenario part
    assert seed(tmp_path, "rome", "pinocchio") == 0  # none given: the default


def test_a_participants_seed_holds_beside_a_scenario_part(tmp_path: Path) -> None:
    assert seed(tmp_path, "rome", "pinocchio", adaptive=True) == 7

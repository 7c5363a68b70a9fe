"""An experiment's stand-in (schemas/experiment.py's StandIn): what it names, and a bad
value refused at load with the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from schemas.base import ConfigError
from schemas.experiment import ExperimentConfig, load_experiment

BASE = """
name = "demo"
duration = 20
{stand_in}

[[participants]]
agent = "kiruna/knatte"
role = "leader"
platform = "knatte"

[[participants]]
agent = "rome/fnatte"
role = "follower"
follow = "kiruna/knatte"
"""


def _write(tmp_path: Path, stand_in: str) -> Path:
    path = tmp_path / "demo.toml"
    path.write_text(BASE.format(stand_in=stand_in), encoding="utf-8")
    return path


def test_a_stand_in_is_read_with_its_defaults(tmp_path: Path) -> None:
    e = load_experiment(_write(tmp_path, 'stand_in = { agent = "rome/twin", preset = "knatte" }'))
    assert e.stand_in is not None
    assert (e.stand_in.agent, e.stand_in.preset, e.stand_in.after) == ("rome/twin", "knatte", 2.0)
    assert e.stand_in.skew == 0.2  # above the 40 ms of Kiruna to Rome and its queueing


def test_no_stand_in_by_default(tmp_path: Path) -> None:
    assert load_experiment(_write(tmp_path, "")).stand_in is None


@pytest.mark.parametrize(
    ("stand_in", "why"),
    [
        ('stand_in = { agent = "rome/twin", preset = "knatte", after = 0.5 }', "stand_in.after"),
        ('stand_in = { agent = "rome/twin", preset = "knatte", skew = 0.4 }', "stand_in.skew"),
        ('stand_in = { agent = "rome/twin", preset = "knatte", skew = 0 }', "stand_in.skew"),
        ('stand_in = { agent = "rome/twin", preset = "gizmo" }', "stand_in.preset"),
        ('stand_in = { agent = "twin", preset = "knatte" }', "stand_in.agent"),
        ('stand_in = { agent = "rome/twin", preset = "knatte", fly = 1 }', "stand_in.fly"),
        ('stand_in = { agent = "rome/fnatte", preset = "knatte" }', "a participant already"),
    ],
)
def test_a_bad_stand_in_fails_at_load_naming_the_file_and_field(
    tmp_path: Path, stand_in: str, why: str
) -> None:
    path = _write(tmp_path, stand_in)
    with pytest.raises(ConfigError) as error:
        load_experiment(path)
    assert str(path) in str(error.value) and why in str(error.value)


def test_a_stand_in_needs_someone_following_the_leader_in_attitude_tracking() -> None:
    data: dict[str, object] = {
        "name": "demo", "duration": 10,
        "stand_in": {"agent": "rome/twin", "preset": "knatte"},
        "participants": [{"agent": "k/l", "role": "leader"}],
    }  # fmt: skip
    with pytest.raises(ValueError, match="nobody follows the leader k/l"):
        ExperimentConfig.model_validate(data)

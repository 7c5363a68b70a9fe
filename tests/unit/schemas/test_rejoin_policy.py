"""Rejoin policies (schemas/config.py's AgentConfig.rejoin, schemas/experiment.py's):
a real platform defaults to operator, a simulated one to auto, the stricter wins."""

from __future__ import annotations

import pytest

from schemas.config import AgentConfig
from schemas.experiment import ExperimentConfig, stricter

AGENT = {"lab": "rome", "name": "fnatte", "role": "leader"}
SERIAL = {"platform": "serial:/dev/ttyUSB0", "wait_start": True}


def test_a_real_platform_defaults_to_operator() -> None:
    assert AgentConfig.model_validate(AGENT | SERIAL).rejoin_policy == "operator"


def test_a_simulated_platform_defaults_to_auto() -> None:
    assert AgentConfig.model_validate(AGENT).rejoin_policy == "auto"
    assert AgentConfig.model_validate(AGENT | {"platform": "knatte"}).rejoin_policy == "auto"


@pytest.mark.parametrize("policy", ["auto", "operator", "never"])
def test_a_given_policy_is_kept(policy: str) -> None:
    assert AgentConfig.model_validate(AGENT | SERIAL | {"rejoin": policy}).rejoin_policy == policy


def test_an_unknown_policy_is_refused() -> None:
    with pytest.raises(ValueError, match="rejoin"):
        AgentConfig.model_validate(AGENT | {"rejoin": "always"})


def _experiment(rejoin: str | None, part: str | None) -> ExperimentConfig:
    follower: dict[str, object] = {"agent": "rome/fnatte", "role": "follower", "follow": "k/l"}
    if part is not None:
        follower["rejoin"] = part
    data: dict[str, object] = {
        "name": "demo",
        "duration": 10,
        "participants": [{"agent": "k/l", "role": "leader"}, follower],
    }
    if rejoin is not None:
        data["rejoin"] = rejoin
    return ExperimentConfig.model_validate(data)


@pytest.mark.parametrize(
    ("experiment", "part", "expected"),
    [
        (None, None, None),  # the platform's default
        ("operator", None, "operator"),
        ("never", None, "never"),
        (None, "never", "never"),
        (None, "auto", "auto"),  # a real platform made auto by its own entry
        ("operator", "auto", "operator"),
        ("never", "operator", "never"),
        ("auto", "operator", "operator"),
    ],
)
def test_the_experiment_bounds_each_participant(
    experiment: str | None, part: str | None, expected: str | None
) -> None:
    exp = _experiment(experiment, part)
    assert exp.rejoin_of(exp.participants[1]) == expected


def test_stricter() -> None:
    assert stricter("auto", "never") == stricter("never", "auto") == "never"
    assert stricter("operator", "auto") == "operator"
    assert stricter("auto", "auto") == "auto"

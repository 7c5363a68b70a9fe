"""The example agent configs in deploy/agents/ load, alone and with the experiment."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.cli import build_parser
from federation.cli.agent import agent_config
from schemas.config import AgentConfig, load_model

ROOT = Path(__file__).resolve().parents[3]
EXPERIMENT = ROOT / "deploy" / "experiments" / "attitude-tracking.toml"


@pytest.mark.parametrize("name", ["knatte", "pinocchio"])
def test_example_agent_configs_load_and_take_part(name: str) -> None:
    path = ROOT / "deploy" / "agents" / f"{name}.toml"
    alone = load_model(AgentConfig, path)
    assert alone.runs_dir == Path("runs")
    args = build_parser().parse_args(
        ["agent", "--agent-config", str(path), "--experiment", str(EXPERIMENT),
         "--lab", alone.lab, "--name", alone.name]
    )  # fmt: skip
    config = agent_config(args)
    assert config.wait_start and config.run_duration == 75.0
    assert config.experiment == EXPERIMENT and config.runs_dir == Path("runs")

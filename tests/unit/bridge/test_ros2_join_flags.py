"""``fedlab bridge ros2 --as``: the joined agent's settings from the bridge's flags."""

from __future__ import annotations

import argparse

import pytest

from federation.cli import bridge as bridge_cli
from federation.cli.common import Formatter
from schemas.config import AgentConfig

JOIN = ["--as", "ros2lab/rover", "--odom", "/rover/odom"]


def parse(*flags: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="fedlab", formatter_class=Formatter)
    bridge_cli.add(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["bridge", "ros2", *flags])


def test_the_joined_agents_sync_window_is_a_flag_defaulting_to_an_agents() -> None:
    """Like any agent's, the joined agent's estimate locks after its sync window: the
    paper's 10 s unless --sync-window says otherwise (a run needs only a locked one)."""
    assert bridge_cli.ros2_join_config(parse(*JOIN)).sync_window == (
        AgentConfig.model_fields["sync_window"].default
    )
    assert bridge_cli.ros2_join_config(parse(*JOIN, "--sync-window", "2")).sync_window == 2.0


@pytest.mark.parametrize("value", ["0", "-1", "nan", "soon"])
def test_a_sync_window_that_is_not_a_positive_number_is_refused(
    value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        parse(*JOIN, "--sync-window", value)
    assert exit_.value.code == 2
    assert "--sync-window" in capsys.readouterr().err

"""``fedlab bench scale``'s arguments are checked before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.bench import scale
from federation.cli import main


def test_a_group_of_no_agents_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="groups of 0"):
        scale.run_one(4, 1.0, tmp_path, group=0)


def test_the_cli_refuses_a_group_of_no_agents(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "scale", "--group", "0"])
    assert exit_.value.code == 2
    assert "--group" in capsys.readouterr().err

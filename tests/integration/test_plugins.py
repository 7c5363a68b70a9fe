"""A scenario defined outside the package (tests/plugins/hold_point.py), installed as a
distribution that declares a ``fedlab.scenarios`` entry point, flown by a real agent
process on loopback; a plug-in that does not load stops the agent at load, naming it.

The distribution is a dist-info folder in the test's own directory, on the agent's
PYTHONPATH beside the plug-in's module: what ``pip install`` of a package declaring
``[project.entry-points."fedlab.scenarios"] hold_point = "hold_point:HoldPoint"`` leaves.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest
from lifecycle import fedlab
from loopback import LEADER, Labs

pytestmark = pytest.mark.integration

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"


def _install(site: Path, name: str, scenarios: dict[str, str], *paths: Path) -> str:
    """A distribution ``name`` in ``site`` declaring ``scenarios`` (name -> module:Class);
    the PYTHONPATH that finds it and ``paths``."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"  # as a wheel names it
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    points = "".join(f"{k} = {v}\n" for k, v in scenarios.items())
    (info / "entry_points.txt").write_text(f"[fedlab.scenarios]\n{points}")
    return os.pathsep.join([str(site), *map(str, paths), os.environ.get("PYTHONPATH", "")])


def test_an_agent_flies_a_scenario_from_an_installed_plugin(
    labs: Labs, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _install(
        tmp_path / "site", "fedlab-hold-point", {"hold_point": "hold_point:HoldPoint"}, PLUGINS
    )
    monkeypatch.setenv("PYTHONPATH", path)  # the agent process's, as installed
    config = tmp_path / "knatte.toml"
    config.write_text(
        'lab = "kiruna"\nname = "knatte"\nrole = "leader"\n'
        '[scenario]\nkind = "hold_point"\n'
        "[scenario.frame]\norigin = [1.0, 0.0]\n"  # its table's centre at x = 1 m
        "[scenario.settings]\npoint = [1.3, -0.2]\nheading_deg = 30.0\n"
    )
    router = labs.router("kiruna")
    agent = labs.agent(LEADER, router, "--agent-config", str(config))
    line = agent.until(
        lambda s: s["counters"].get("hold_point_references", 0) > 20,
        timeout=30,
        what="the plug-in scenario's references counted in status",
    )
    # A kinematic platform is where its reference puts it: the point, in the common frame.
    x, y, heading = line["pose"][:3]
    assert (x, y) == pytest.approx((1.3, -0.2), abs=1e-6)
    assert heading == pytest.approx(math.radians(30.0), abs=1e-6)
    assert line["hold"] is None and line["counters"]["workspace_holds"] == 0


def test_a_plugin_that_does_not_load_stops_the_agent_at_load(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    broken = tmp_path / "plugins"
    broken.mkdir()
    (broken / "broken_scenario.py").write_text("raise ImportError('needs libfoo 2')\n")
    path = _install(tmp_path / "site", "fedlab-broken", {"broken": "broken_scenario:X"}, broken)
    monkeypatch.setenv("PYTHONPATH", path)
    config = tmp_path / "knatte.toml"
    config.write_text(
        'lab = "kiruna"\nname = "knatte"\nrole = "leader"\n[scenario]\nkind = "broken"\n'
    )
    done, _ = fedlab("agent", "--agent-config", str(config), "-e", "tcp/127.0.0.1:9", timeout=60)
    assert done.returncode == 2, done.stderr
    assert (
        f"{config}: field 'scenario.kind': Value error, scenario 'broken': "
        "entry point broken_scenario:X of distribution 'fedlab-broken' does not load: "
        "ImportError: needs libfoo 2"
    ) in done.stderr

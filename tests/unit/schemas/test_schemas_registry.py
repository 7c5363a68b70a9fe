"""Kinds found by name (schemas/registry.py): built-ins, registered in code, and entry
points of installed distributions, each failure named at lookup."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from schemas.platform import PLATFORMS
from schemas.registry import Registry, RegistryError
from schemas.scenario import SCENARIOS

GROUP = "fedlab.tests_things"


def _floats(name: str, obj: object) -> float:
    if not isinstance(obj, float):
        raise TypeError(f"{obj!r} is not a float")
    return obj


def _registry() -> Registry[float]:
    return Registry("thing", GROUP, {"pi": "math:pi", "broken": "no_such_module:X"}, _floats)


def _distribution(site: Path, name: str, points: dict[str, str], group: str = GROUP) -> None:
    """An installed distribution in ``site`` (a dist-info folder) declaring ``points``."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"  # as a wheel names it
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    lines = "".join(f"{k} = {v}\n" for k, v in points.items())
    (info / "entry_points.txt").write_text(f"[{group}]\n{lines}")


def test_a_built_in_is_found_by_name() -> None:
    registry = _registry()
    assert registry.get("pi") == pytest.approx(3.14159, abs=1e-5)
    assert "pi" in registry and "nope" not in registry and 3 not in registry
    assert registry.names() == ["broken", "pi"]


def test_an_unknown_name_lists_the_known_ones() -> None:
    with pytest.raises(RegistryError, match=r"unknown thing 'tau' \(known: broken, pi\)"):
        _registry().get("tau")


def test_a_built_in_that_does_not_import_names_its_module() -> None:
    with pytest.raises(RegistryError, match="no_such_module:X does not load: ModuleNotFound"):
        _registry().get("broken")


def test_registering_in_code() -> None:
    registry = _registry()
    assert registry.register("tau", 6.28) == 6.28
    assert registry.get("tau") == 6.28 and "tau" in registry.names()
    tau = registry.get("tau")
    registry.register("tau", tau)  # the same object again: a module imported twice
    with pytest.raises(RegistryError, match="'tau' is already registered"):
        registry.register("tau", 6.3)
    with pytest.raises(RegistryError, match="'pi' is built in"):
        registry.register("pi", 3.0)
    with pytest.raises(RegistryError, match="thing name"):
        registry.register("Not A Name", 1.0)
    with pytest.raises(RegistryError, match=r"'e' \(registered in code\): 2 is not a float"):
        registry.register("e", 2)
    registry.unregister("tau")
    assert "tau" not in registry


def test_an_entry_point_is_found_when_its_name_is_looked_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "things_plugin.py").write_text("E = 2.718\nNOT_A_FLOAT = 'e'\n")
    _distribution(
        tmp_path, "things-plugin", {"e": "things_plugin:E", "s": "things_plugin:NOT_A_FLOAT"}
    )
    registry = _registry()
    assert "e" not in registry
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "e" in registry and registry.names() == ["broken", "e", "pi", "s"]
    assert "things_plugin" not in sys.modules  # listed, not imported
    assert registry.get("e") == 2.718
    with pytest.raises(RegistryError, match=r"'s' \(entry point things_plugin:NOT_A_FLOAT of "):
        registry.get("s")


def test_an_entry_point_that_fails_to_import_names_its_distribution_and_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "bad_things.py").write_text("raise RuntimeError('no licence file')\n")
    _distribution(tmp_path, "bad-things", {"bad": "bad_things:X"})
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(
        RegistryError,
        match="thing 'bad': entry point bad_things:X of distribution 'bad-things' does not "
        "load: RuntimeError: no licence file",
    ):
        _registry().get("bad")


def test_a_name_claimed_twice_is_refused_naming_both(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "two_things.py").write_text("A = 1.0\nB = 2.0\nPI = 3.0\n")
    _distribution(tmp_path / "one", "first", {"x": "two_things:A", "pi": "two_things:PI"})
    _distribution(tmp_path / "two", "second", {"x": "two_things:B", "pi": "math:pi"})
    for path in (tmp_path, tmp_path / "one", tmp_path / "two"):
        monkeypatch.syspath_prepend(str(path))
    registry = _registry()
    either = "'(first|second)'"
    with pytest.raises(RegistryError, match=rf"'x' is claimed 2 times: .*{either}.*{either}"):
        registry.get("x")
    # A built-in is never shadowed; a distribution naming the built-in itself is no claim.
    with pytest.raises(RegistryError, match=r"'pi' is claimed 2 times: built in \(math:pi\); "):
        registry.get("pi")


def test_the_built_in_scenarios_and_platform_kinds() -> None:
    assert {"attitude-tracking", "formation", "docking"} <= set(SCENARIOS.names())
    assert {"kinematic", "simulated", "serial"} <= set(PLATFORMS.names())
    for name in ("attitude-tracking", "formation", "docking"):
        assert SCENARIOS.get(name).name == name
    for name in ("kinematic", "simulated", "serial"):
        assert PLATFORMS.get(name).kind == name
    assert PLATFORMS.get("serial").hardware and not PLATFORMS.get("simulated").hardware

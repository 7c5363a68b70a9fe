"""Exactly one module decides holds: the supervisor's state changes only through
:class:`federation.core.holds.Supervisor`, which only
:mod:`federation.runtime.safety` makes and drives, and no other library module holds
or releases an agent's platform (the platforms' own code, under agents/, holds what
it wraps)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OWNER = "federation/runtime/safety.py"


def _library() -> list[tuple[str, ast.Module]]:
    out = []
    for package in ("federation", "agents", "schemas"):
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            out.append((rel, ast.parse(path.read_text(encoding="utf-8"), rel)))
    return out


def _calls(tree: ast.Module) -> list[ast.Call]:
    return [node for node in ast.walk(tree) if isinstance(node, ast.Call)]


def test_only_the_safety_module_makes_a_supervisor() -> None:
    makers = {
        rel
        for rel, tree in _library()
        for call in _calls(tree)
        if isinstance(call.func, ast.Name) and call.func.id == "Supervisor"
    }
    assert makers == {OWNER}


def test_no_other_library_module_holds_or_releases_an_agents_platform() -> None:
    # agents/ holds the platforms themselves (a framed platform holds the one it wraps,
    # a simulated one its chain); in federation/ only the safety module acts on one.
    found = set()
    for rel, tree in _library():
        if not rel.startswith("federation/"):
            continue
        for call in _calls(tree):
            func = call.func
            acts = isinstance(func, ast.Attribute) and func.attr in ("hold", "release")
            if acts and "platform" in ast.unparse(func.value) and not call.args:  # type: ignore[union-attr]
                found.add(rel)
    assert found <= {OWNER}, found


def test_no_hold_is_written_as_a_bare_string_attribute() -> None:
    # The supervisor's Hold enum is the one vocabulary: no module keeps a hold of its own
    # in an attribute named for one.
    written = []
    for rel, tree in _library():
        for node in ast.walk(tree):
            targets = node.targets if isinstance(node, ast.Assign) else []
            if isinstance(node, ast.AnnAssign | ast.AugAssign):
                targets = [node.target]
            for target in targets:
                if isinstance(target, ast.Attribute) and target.attr == "hold_reason":
                    written.append(f"{rel}:{node.lineno}")
    assert written == []

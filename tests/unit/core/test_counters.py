"""Counters are named once (:mod:`federation.core.counters`): every member has a row,
no two share a name, the library names none by a bare string, and what an agent's
status says is all members."""

from __future__ import annotations

import ast
import json
from pathlib import Path
from typing import Any, get_args

import pytest

from agents.gnc import CLOSED_COUNT, Reason
from agents.serial.emulator import _RX
from agents.serial.protocol import FrameDecoder
from federation.cli import main
from federation.core.counters import BY_COUNT, ROWS, Count, counters_table_markdown
from federation.runtime.agent import AgentRuntime
from federation.runtime.clock import ExecClock
from schemas.config import AgentConfig

ROOT = Path(__file__).parents[3]
LIBRARY = ("federation", "agents", "schemas")
TABLE = Path("federation/core/counters.py")

COUNTER_ATTRS = frozenset({"counters", "_counters", "_host", "workspace_counters"})
"""Attributes that hold counters: a key of one is a counter's name."""
COUNTING = frozenset({"count", "_count", "_count_all", "oversized", "end_run_here", "_refuse"})
"""Functions that take a counter, which must say so (a parameter typed ``Count``); the
scan finds every other such function by its annotation."""
NOT_COUNTERS = {
    ("federation/runtime/collect.py", "count"): "CollectResult.count: why a chunk was "
    "fetched again (free text for the collect report), not a status counter",
}
"""(module, function) pairs whose string arguments are no counter's name."""


# -- the table ---------------------------------------------------------------------------
def test_every_member_has_one_row_in_the_enum_order() -> None:
    assert [row.count for row in ROWS] == list(Count)
    assert set(BY_COUNT) == set(Count)
    for row in ROWS:
        assert row.meaning.strip() and row.by, row.count
        assert "|" not in row.meaning, f"{row.count}: a '|' breaks docs/counters.md's table"


def test_no_two_members_share_a_name() -> None:
    # An Enum makes a second member with a value already taken an alias of the first:
    # it is in __members__, not in the iteration.
    values = [member.value for member in Count.__members__.values()]
    assert len(values) == len(set(values)) == len(Count)
    assert all(v == v.strip().lower() and " " not in v for v in values)


def test_the_closed_counters_are_one_per_reason_of_the_chain() -> None:
    assert set(CLOSED_COUNT) == set(get_args(Reason))
    for reason, count in CLOSED_COUNT.items():
        assert count.value == f"closed_{reason}"


def test_the_emulated_devices_rx_counters_are_its_decoders() -> None:
    assert set(_RX) == set(FrameDecoder.COUNTERS)
    for count, rx in _RX.items():
        assert rx.value == f"rx_{count.value}"
    assert all(isinstance(k, Count) for k in FrameDecoder().counters)


def test_docs_counters_md_is_the_table() -> None:
    doc = (ROOT / "docs" / "counters.md").read_text(encoding="utf-8")
    assert counters_table_markdown() in doc, "regenerate: fedlab schemas --counters"


def test_fedlab_schemas_counters_prints_the_table(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schemas", "--counters"]) == 0
    assert capsys.readouterr().out == counters_table_markdown()


# -- the scan ----------------------------------------------------------------------------
def _names(node: ast.expr | None) -> list[ast.expr]:
    """The string literals and f-strings that ``node`` may evaluate to."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node]
    if isinstance(node, ast.JoinedStr):
        return [node]
    if isinstance(node, ast.IfExp):
        return _names(node.body) + _names(node.orelse)
    if isinstance(node, ast.BinOp):  # "closed_" + reason
        return [node] if _names(node.left) or _names(node.right) else []
    return []


def _typed_count(annotation: ast.expr | None) -> bool:
    return annotation is not None and "Count" in ast.unparse(annotation).replace("Counter", "")


def _call_name(func: ast.expr) -> str | None:
    if isinstance(func, ast.Attribute):
        return func.attr
    return func.id if isinstance(func, ast.Name) else None


def counting_functions(trees: dict[str, ast.Module]) -> dict[str, dict[str, set[int | str]]]:
    """Every function taking a counter (a parameter typed ``Count``): name -> module ->
    the positions and names of its counter parameters (``self`` not counted)."""
    found: dict[str, dict[str, set[int | str]]] = {}
    for module, tree in trees.items():
        for node in ast.walk(tree):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            params = node.args.posonlyargs + node.args.args
            skip = 1 if params and params[0].arg in ("self", "cls") else 0
            slots: set[int | str] = set()
            for i, param in enumerate(params[skip:]):
                if _typed_count(param.annotation):
                    slots |= {i, param.arg}
            if slots:
                found.setdefault(node.name, {}).setdefault(module, set()).update(slots)
    return found


def _dict_keys(value: ast.expr) -> list[ast.expr]:
    if isinstance(value, ast.Dict):
        return [k for k in value.keys if k is not None]
    if isinstance(value, ast.DictComp):
        return [value.key]
    if isinstance(value, ast.Call) and _call_name(value.func) == "fromkeys" and value.args:
        keys = value.args[0]
        return list(keys.elts) if isinstance(keys, ast.Tuple | ast.List | ast.Set) else []
    return []


def _calls(tree: ast.Module, module: str, counting: dict[str, Any]) -> list[ast.expr]:
    """Counters named by a string in a call: to a function that takes a counter, to
    ``Count(...)``, or to a counter dict's ``get``."""
    found: list[ast.expr] = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _call_name(node.func)
        if name == "Count":
            found += node.args  # a member by its attribute, never looked up by a string
            continue
        if name == "get" and isinstance(node.func, ast.Attribute) and node.args:
            owner = node.func.value
            if isinstance(owner, ast.Attribute) and owner.attr in COUNTER_ATTRS:
                found += _names(node.args[0])
            continue
        if name is None or (module, name) in NOT_COUNTERS or name not in counting:
            continue
        modules = counting[name]
        if name.startswith("_") and module not in modules:
            continue  # another module's private function of the same name
        slots = set().union(*modules.values())
        for i, arg in enumerate(node.args):
            if i in slots:
                found += _names(arg)
        for keyword in node.keywords:
            if keyword.arg in slots:
                found += _names(keyword.value)
    return found


def _dicts(tree: ast.Module) -> list[ast.expr]:
    """Counters named by a string as a key of a counter dict: indexed, assigned, or
    built by a ``counters`` property."""
    found: list[ast.expr] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            value = node.value
            if isinstance(value, ast.Attribute) and value.attr in COUNTER_ATTRS:
                found += _names(node.slice)
        elif isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if any(
                isinstance(t, ast.Attribute | ast.Name)
                and (t.attr if isinstance(t, ast.Attribute) else t.id) in COUNTER_ATTRS
                for t in targets
            ):
                found += [n for key in _dict_keys(node.value) for n in _names(key)]
        elif isinstance(node, ast.FunctionDef) and node.name == "counters":
            for inner in ast.walk(node):
                if isinstance(inner, ast.expr):
                    found += [n for key in _dict_keys(inner) for n in _names(key)]
    return found


def bare_counters(trees: dict[str, ast.Module]) -> list[str]:
    """Where a counter is named by a string literal or built by an f-string, as
    ``module:line: source``."""
    counting = counting_functions(trees)
    out = []
    for module, tree in sorted(trees.items()):
        for node in _calls(tree, module, counting) + _dicts(tree):
            out.append(f"{module}:{node.lineno}: {ast.unparse(node)}")
    return sorted(set(out))


def _library() -> dict[str, ast.Module]:
    trees = {}
    for package in LIBRARY:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if rel != TABLE:
                trees[rel.as_posix()] = ast.parse(path.read_text(encoding="utf-8"), str(rel))
    return trees


def test_the_library_names_no_counter_by_a_bare_string() -> None:
    found = bare_counters(_library())
    assert not found, (
        "name counters by their federation.core.counters.Count member (add one, with "
        "its row in ROWS, for a new counter):\n" + "\n".join(found)
    )


def test_every_function_that_takes_a_counter_types_it_count() -> None:
    counting = counting_functions(_library())
    assert set(counting) >= COUNTING | {"_reject"}
    # Each of the agent's count methods and the protocols its parts count through.
    assert {
        "federation/runtime/agent/runtime.py",
        "federation/runtime/agent/reporting.py",
        "federation/runtime/agent/services.py",
        "federation/runtime/links.py",
        "federation/runtime/loop.py",
        "federation/bridge/core.py",
    } <= set(counting["count"])


def test_the_scan_finds_every_way_of_naming_a_counter_bare() -> None:
    source = """
def count(self, name: Count) -> None: ...
def _count_all(users, name: Count) -> None: ...
def end_run_here(self, counter: Count, detail: str, host: float) -> None: ...

class Bad:
    def __init__(self):
        self.counters = {"a": 0, Count.POSE_RECEIVED: 0}
        self._host: dict[Count, int] = dict.fromkeys(("b",), 0)

    @property
    def counters(self):
        return {f"rx_{k}": v for k, v in self.decoder.counters.items()}

    def step(self, reason, lost, users, status):
        self.count("c")
        _count_all(users, "d")
        self.commands.end_run_here("e", "detail", 0.0)
        self.counters[f"closed_{reason}"] += 1
        self.workspace_counters["f" if lost else Count.RESTARTS] += 1
        self._host["g"] += 1
        self.counters[Count("h")] += 1
        self.counters["i_" + reason] += 1
        status.counters.get("j")
        self.count(Count.POSE_RECEIVED)
        "k".count("l")  # a str's count: the same name, and flagged too
"""
    found = bare_counters({"bad.py": ast.parse(source)})
    named = sorted(line.split(": ", 1)[1] for line in found)
    bare = ["a", "b", "c", "d", "e", "f", "g", "h", "j", "l"]
    built = ["f'rx_{k}'", "f'closed_{reason}'", "'i_' + reason"]
    assert named == sorted([*map(repr, bare), *built])
    assert bare_counters({"federation/runtime/collect.py": ast.parse('result.count("x")')}) == []


# -- what an agent says ------------------------------------------------------------------
class _Sink:
    def __init__(self, into: list[str]):
        self.into = into

    def put(self, payload: str, **kwargs: Any) -> None:
        self.into.append(payload)


class _Payload:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, data: bytes):
        self.payload = _Payload(data)
        self.key_expr = "fedlab/default/@control"


def test_an_agents_status_counters_are_all_members() -> None:
    now = [1000.0]
    clock = ExecClock(source=lambda: now[0])
    config = AgentConfig(
        lab="kiruna", name="f", role="follower", follow="rome/l", platform="knatte"
    )
    agent = AgentRuntime(config, session=None, clock=clock)  # type: ignore[arg-type]
    statuses: list[str] = []
    agent.reporter.publisher = _Sink(statuses)
    agent.publish_pose()  # before the simulated cameras' first fix: withheld
    for _ in range(20):
        now[0] += 0.01
        agent.control_step()  # held, waiting for its run: every valve closed
    agent.commands.on_control(_Sample(b"{not json"))  # type: ignore[arg-type]
    agent.publish_status()
    counters = json.loads(statuses[-1])["counters"]
    assert counters, "a status with no counters proves nothing"
    assert set(counters) <= {c.value for c in Count}, set(counters) - set(Count)
    assert counters[Count.POSE_WITHHELD_NO_FIX] == counters[Count.CONTROL_MALFORMED] == 1
    assert counters[Count.CLOSED_HELD] == 20
    assert Count.FIX_REJECTED in counters  # the chain's, at 0
    assert all(isinstance(k, Count) for k in agent.counter_snapshot())

"""The command line: help with an example on every command, version, clear config and
network errors, and argparse only in federation.cli."""

from __future__ import annotations

import argparse
import ast
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from federation import cli
from federation.cli import build_parser, main
from federation.cli.common import open_interruptible, signal_handlers_kept, stop_on_signals
from federation.core.keys import AgentId
from federation.fleet.launch import free_port
from federation.runtime import control, refclock
from federation.runtime.router import load_router_config
from federation.runtime.session import ConnectError
from schemas import export
from schemas.config import ConfigError, ZenohOptions
from schemas.messages import Command

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ("federation", "agents", "schemas")  # every package but federation/cli
ENTRY_POINT = ROOT / "federation" / "__main__.py"  # python -m federation: calls the CLI


def parsers(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every command and subcommand's parser, with its words after ``fedlab``."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from parsers(child, (*path, name))


COMMANDS = sorted(path[0] for path, _ in parsers(build_parser()) if len(path) == 1)


def fedlab(*args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "federation", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def test_commands_exist() -> None:
    assert {"router", "agent", "demo"} <= set(COMMANDS)
    expected = {"ctl", "monitor", "link", "bridge", "report", "analyze", "bench", "certs"}
    assert expected | {"schemas", "emulate-device"} <= set(COMMANDS)


def test_every_command_module_adds_and_runs() -> None:
    for name in cli.COMMANDS:
        module = cli.command_module(name)
        assert callable(module.add) and callable(module.run), module.__name__
    assert sorted(cli.COMMANDS) == COMMANDS


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["router", "--lab", "x"], "router"),
        (["--log-level", "debug", "ctl", "status"], "ctl"),
        (["--log-level=debug", "emulate-device"], "emulate-device"),
        (["--version"], None),
        (["nosuch", "router"], None),
        (["--log-level", "router"], None),  # "router" is the level here (refused later)
    ],
)
def test_the_command_is_found_before_parsing(argv: list[str], command: str | None) -> None:
    assert cli.chosen_command(argv) == command


def test_a_router_command_line_does_not_import_the_gnc_or_the_report() -> None:
    code = (
        "import sys, federation.cli as c; c.build_parser(('router',)); "
        "print(sorted(m for m in ('filterpy', 'agents.gnc', 'federation.report', "
        "'matplotlib', 'cryptography') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_agents_do_not_import_scipy() -> None:
    """No agent loads filterpy, python-control, scipy or matplotlib, kinematic or
    navigating: they cost a second of CPU at each agent's start (the navigation filter
    does filterpy's arithmetic itself, the heading-loop margins are closed forms)."""
    heavy = "('filterpy', 'control', 'scipy', 'matplotlib')"
    code = (
        "import sys; from federation.runtime.agent import AgentRuntime; "
        "from federation.runtime.agent import reporting; "
        "from agents.platform import make_platform; make_platform('kinematic'); "
        f"print(sorted(m for m in {heavy} if m in sys.modules)); "
        "make_platform('knatte'); "
        f"print(sorted(m for m in {heavy} if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.split() == ["[]", "[]"], out.stdout


@pytest.mark.parametrize(
    ("path", "parser"),
    [pytest.param(path, p, id=" ".join(path) or "fedlab") for path, p in parsers(build_parser())],
)
def test_every_command_and_subcommand_has_help_with_an_example(
    path: tuple[str, ...], parser: argparse.ArgumentParser
) -> None:
    text = parser.format_help()
    assert parser.description or not path, f"fedlab {' '.join(path)}: no description"
    assert "Example" in text, f"fedlab {' '.join(path)}: no example in its help"
    assert " ".join(("fedlab", *path)) in text.split("Example", 1)[1]
    for action in parser._actions:
        assert action.help or isinstance(action, argparse._SubParsersAction), (path, action)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_help_with_an_example(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "Example" in out and f"fedlab {command}" in out


@pytest.mark.parametrize("command", ["router", "agent"])
def test_session_commands_take_zenohs_usual_flags(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = capsys.readouterr().out
    for flag in ("-m", "--mode", "-e", "--connect", "-l", "--listen", "-c", "--config", "--cfg"):
        assert f"{flag} " in out or f"{flag}," in out, flag


def test_version() -> None:
    result = fedlab("--version")
    assert result.returncode == 0
    assert result.stdout.startswith("fedlab 0.")


def test_python_dash_m_and_console_script_agree() -> None:
    script = Path(sys.executable).with_name("fedlab")
    if not script.exists():
        pytest.skip("console script not installed in this interpreter's bin")
    result = subprocess.run([str(script), "--version"], capture_output=True, text=True, timeout=30)
    assert result.stdout == fedlab("--version").stdout


def test_bad_agent_config_file_names_file_and_field(tmp_path: Path) -> None:
    config = tmp_path / "rome.toml"
    config.write_text('lab = "rome"\nname = "pinocchio"\nrole = "follower"\nsync_period = -1\n')
    result = fedlab("agent", "--agent-config", str(config), "-e", "tcp/127.0.0.1:9")
    assert result.returncode == 2
    assert str(config) in result.stderr
    assert "sync_period" in result.stderr and "greater than 0" in result.stderr


@pytest.mark.parametrize(
    ("command", "said"),
    [
        ("agent --role leader --lab Kiruna --name knatte", ("field 'lab'", "lowercase")),
        ("agent --role follower --lab rome --name p", ("follow",)),
        ("router --lab kiruna -l nowhere", ("nowhere", "PROTOCOL/ADDRESS")),
        ("router --lab kiruna -l tcp/127.0.0.1:9 --cfg no/such/key:1", ("no/such/key",)),
    ],
)
def test_bad_invocation_exits_2_saying_why(command: str, said: tuple[str, ...]) -> None:
    result = fedlab(*command.split())
    assert result.returncode == 2
    for text in said:
        assert text in result.stderr, text


@pytest.mark.parametrize("lab", ["kiruna", "rome"])
def test_shipped_router_configs_load(lab: str) -> None:
    path = ROOT / "deploy" / "routers" / f"{lab}.json5"
    settings, _ = load_router_config(ZenohOptions(config=path), None)
    assert settings.lab == lab
    assert settings.listen
    if lab == "rome":
        assert settings.connect, "rome dials kiruna"
    else:
        assert not settings.connect, "kiruna only listens"


def test_router_config_without_lab_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "r.json5"
    path.write_text('{mode: "router", listen: {endpoints: ["tcp/127.0.0.1:9"]}}')
    with pytest.raises(ConfigError, match=r"r\.json5: field 'metadata\.lab'"):
        load_router_config(ZenohOptions(config=path), None)


def signalled(args: list[str], sig: int, after: str) -> tuple[bool, int, str]:
    """Run ``fedlab ARGS`` until it prints a line containing ``after`` (at most 30 s),
    then send ``sig``: whether it was still running then, its exit code and its output
    (killed if it outlives 10 s more)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "federation", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    lines: list[str] = []
    seen = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:  # ends when the process closes its output
            lines.append(line)
            if after in line:
                seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        seen.wait(30.0)
        running = proc.poll() is None
        if running:
            os.kill(proc.pid, sig)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        reader.join(10)
    return running, proc.returncode, "".join(lines)


def test_router_from_shipped_file_runs_and_stops_on_sigterm() -> None:
    path = ROOT / "deploy" / "routers" / "kiruna.json5"
    listen = f"tcp/127.0.0.1:{free_port()}"
    running, code, out = signalled(["router", "-c", str(path), "-l", listen], signal.SIGTERM, "up")
    assert running, out
    assert code == 0, out
    assert "router kiruna up" in out and listen in out


# SIGHUP: a terminal or SSH session that drops (the agent had died without closing).
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_agent_waiting_for_its_router_stops_cleanly(sig: int) -> None:
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    args = ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte", "-e", nowhere]
    # Signalled once it says it waits (its first note comes after 2 s of waiting).
    running, code, out = signalled(args, sig, "waiting for the router")
    assert running, "an agent keeps waiting for its router"
    assert code == 0, out
    assert "waiting for the router" in out


@pytest.mark.parametrize("command", ["agent", "host", "foxglove", "bridge"])
def test_a_service_given_a_timeout_gives_up_on_its_router_naming_it(
    command: str, tmp_path: Path
) -> None:
    """Long-running commands wait for their router by default; with ``--timeout`` they
    exit 1 within it, naming the endpoint, as the short-lived ones do."""
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    agent = ["--role", "leader", "--lab", "kiruna", "--name", "knatte"]
    if command == "host":
        file = tmp_path / "a.toml"
        file.write_text('lab = "kiruna"\nname = "knatte"\nrole = "leader"\n')
        agent = [str(file)]
    elif command == "foxglove":
        agent = ["--port", "0"]
    elif command == "bridge":
        listen, peer = (f"127.0.0.1:{free_port()}" for _ in range(2))
        agent = ["udp", "--as", "kiruna/legacy", "--listen", listen, "--peer", peer]
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "federation", *command.split(), *agent, "-e", nowhere,
         "--timeout", "1"],
        capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=30, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert time.monotonic() - started < 15
    assert nowhere.removeprefix("tcp/") in done.stderr, done.stderr


# -- errors --------------------------------------------------------------------------
def test_network_failure_is_not_a_config_error() -> None:
    assert not issubclass(ConnectError, ConfigError)
    assert not issubclass(ConnectError, ValueError)

    def refuse(conf: Any) -> Any:
        raise RuntimeError("no route")

    with pytest.raises(ConnectError, match=r"cannot open a Zenoh session.*: no route"):
        open_interruptible(refuse, None, threading.Event())


def test_connect_error_exits_1_with_a_clear_message(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def unreachable(args: argparse.Namespace, stop: threading.Event) -> Any:
        raise ConnectError("cannot open a Zenoh session: router unreachable")

    monkeypatch.setattr(cli.command_module("ctl"), "open_session", unreachable)
    assert main(["ctl", "abort", "-e", "tcp/127.0.0.1:9"]) == 1
    assert "fedlab ctl: error: cannot open a Zenoh session" in capsys.readouterr().err


def test_main_puts_signal_handlers_back(monkeypatch: pytest.MonkeyPatch) -> None:
    before = signal.getsignal(signal.SIGTERM)
    with signal_handlers_kept():
        stop_on_signals()
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before

    def stops(args: argparse.Namespace, stop: threading.Event) -> None:
        return None  # as if a signal stopped it before the router answered

    monkeypatch.setattr(cli.command_module("monitor"), "open_session", stops)
    assert main(["monitor", "--once", "-e", "tcp/127.0.0.1:9"]) == 0
    assert signal.getsignal(signal.SIGTERM) is before


_SLOW_STOP = """
import sys, time
from federation.cli import common
common.STOP_REPORT_AFTER = 0.3
stop = common.stop_on_signals()
print("ready", flush=True)
stop.wait(30)
time.sleep(3)  # a stop that takes too long: what is it waiting for?
"""


_SIGNAL_INSIDE_WAIT = """
import os, signal
from federation.cli import common
stop = common.stop_on_signals()
with stop._cond:  # as the main thread is, for a moment, inside stop.wait() or stop.set()
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(100))  # the handler runs here, between two bytecodes
print("set:", stop.wait(5), flush=True)
"""


def test_a_signal_while_the_main_thread_is_inside_the_stop_event_still_stops_it() -> None:
    # The handler had called stop.set(), which takes the event's lock: arriving while the
    # main thread held it (inside a loop's stop.wait(0.1)), it waited for itself for ever,
    # and the bridge outlived SIGTERM (CI, stop 36). Bounded: a hang fails, not stalls.
    proc = subprocess.Popen(
        [sys.executable, "-c", _SIGNAL_INSIDE_WAIT], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        out, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=10)
        pytest.fail(f"the process hung on its own stop event:\n{err[-2000:]}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert out == "set: True\n" and proc.returncode == 0, (out, err)


_SIGNALS_APART = """
import os, signal, time
from federation.cli import common
from federation.runtime.signals import stop_event
common.STOP_REPORT_AFTER = 0.5
term_only = stop_event([signal.SIGTERM])  # as the network bench's
with common.signal_handlers_kept():  # as main() runs a command
    command = common.stop_on_signals()
    os.kill(os.getpid(), signal.SIGINT)
    print("command stopped:", command.wait(5), flush=True)
time.sleep(0.3)
print("SIGTERM-only event set:", term_only.is_set(), flush=True)
time.sleep(1.0)  # past STOP_REPORT_AFTER: no stack dump once the command has returned
pid = os.fork()
if pid == 0:  # a child's signal is its own
    child = stop_event([signal.SIGTERM])
    os.kill(os.getpid(), signal.SIGTERM)
    os._exit(0 if child.wait(5) else 1)
_, code = os.waitpid(pid, 0)
print("child stopped itself:", code == 0, flush=True)
time.sleep(0.3)
print("parent's event set by the child:", term_only.is_set(), flush=True)
"""


def test_a_signal_sets_only_its_own_events_in_its_own_process() -> None:
    # The relay had set every live event whatever signals it waited for; after a fork the
    # child's signals went to the parent's relay; a dump armed by a command's signal
    # went off seconds after main() had returned.
    done = subprocess.run(
        [sys.executable, "-c", _SIGNALS_APART], cwd=ROOT, text=True, capture_output=True,
        timeout=60,
    )  # fmt: skip
    assert done.stdout.splitlines() == [
        "command stopped: True",
        "SIGTERM-only event set: False",
        "child stopped itself: True",
        "parent's event set by the child: False",
    ], (done.stdout, done.stderr)
    assert "Timeout" not in done.stderr, done.stderr


def test_a_stop_that_takes_too_long_says_where_each_thread_is() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_STOP], cwd=ROOT, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait(10)
    assert "Timeout (0:00:00.300000)!" in err and "in <module>" in err, err


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "sync", "--duration", "5"],  # not past the 10 s sync phase
        ["bench", "scale", "--agents", "1"],
        ["ctl", "start", "--reference", "nolab"],
        ["ctl", "start", "--federation", "Bad/Name"],
        ["monitor", "--wait", "-1"],
    ],
)
def test_bad_values_are_refused_by_the_parser(argv: list[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2


# -- fedlab schemas ------------------------------------------------------------------
def test_schemas_writes_then_checks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schemas", "--out", str(tmp_path)]) == 0
    assert len(list(tmp_path.glob("*.schema.json"))) == len(export.MODELS)
    assert main(["schemas", "--check", "--out", str(tmp_path)]) == 0
    (tmp_path / "Command.schema.json").write_text("{}\n")
    capsys.readouterr()
    assert main(["schemas", "--check", "--out", str(tmp_path)]) == 1
    assert "Command.schema.json" in capsys.readouterr().err


# -- fedlab ctl: what it decides without a network ------------------------------------
def test_ctl_reference_is_the_flag_then_the_experiment_then_the_one_leader() -> None:
    seen = {"kiruna/knatte": {"role": "leader"}, "rome/pinocchio": {"role": "follower"}}
    given = AgentId("rome", "pinocchio")
    assert control.choose_reference(given, None, seen) == given
    assert control.choose_reference(None, None, seen) == AgentId("kiruna", "knatte")
    with pytest.raises(ConfigError, match="found 0 leaders"):
        control.choose_reference(None, None, {"rome/pinocchio": {"role": "follower"}})
    two = seen | {"rome/other": {"role": "leader"}}
    with pytest.raises(ConfigError, match="found 2 leaders"):
        control.choose_reference(None, None, two)


def test_ctl_result_is_ok_when_every_expected_agent_confirmed() -> None:
    command = Command(command="abort", seq=1)
    expected = frozenset({"kiruna/knatte", "rome/pinocchio"})
    modes = {"kiruna/knatte": "aborted", "rome/pinocchio": "running", "x/y": "running"}
    result = control.ControlResult(command, AgentId("kiruna", "knatte"), expected, modes, 0.1)
    assert not result.ok and result.pending == ["rome/pinocchio"]
    done = control.ControlResult(
        command, result.reference, expected, modes | {"rome/pinocchio": "aborted"}, 0.1
    )
    assert done.ok and done.pending == []


# -- layering: argparse only in federation/cli ---------------------------------------
def _library_files() -> Iterator[Path]:
    for package in LIBRARY:
        for path in sorted((ROOT / package).rglob("*.py")):
            if (ROOT / "federation" / "cli") not in path.parents and path != ENTRY_POINT:
                yield path


def test_library_never_imports_argparse_nor_defines_a_command() -> None:
    found = []
    for path in _library_files():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        where = path.relative_to(ROOT)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Import | ast.ImportFrom):
                continue
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                names = [node.module or ""]
            if any(n == "argparse" or n.startswith(("argparse.", "federation.cli")) for n in names):
                found.append(f"{where}:{node.lineno} imports {', '.join(names)}")
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and (
                node.name == "register" or node.name.startswith("cmd_")
            ):
                found.append(f"{where}:{node.lineno} defines {node.name}()")
    assert not found, "command-line code outside federation/cli:\n" + "\n".join(found)


def test_ctl_files_a_status_under_the_agent_its_key_names_only() -> None:
    """An insider may write only its own keys; a status it publishes there naming
    another agent ("kiruna/knatte: aborted") must not count as that agent's."""
    import json as json_

    from federation.runtime.control import Federation

    class Session:
        def declare_subscriber(self, *args: Any, **kwargs: Any) -> Any:
            return None

    class Sample:
        def __init__(self, key: str, status: dict[str, Any]):
            self.key_expr = key
            self.payload = type("P", (), {"to_bytes": lambda _: json_.dumps(status).encode()})()

    fed = Federation(Session(), "default")
    fed._on_status(Sample("fedlab/default/lab3/ghost/status", {"agent": "kiruna/knatte",
                                                                "mode": "aborted"}))  # fmt: skip
    assert fed.snapshot() == {} and fed.mismatched == 1
    fed._on_status(Sample("fedlab/default/kiruna/knatte/status", {"agent": "kiruna/knatte",
                                                                  "mode": "running"}))  # fmt: skip
    assert fed.snapshot()["kiruna/knatte"]["mode"] == "running"


class _Recorder:
    """A session that records what ctl puts (nothing is sent)."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, dict[str, Any], dict[str, Any]]] = []

    def put(self, key: str, payload: str, **options: Any) -> None:
        import json as json_

        self.puts.append((key, json_.loads(payload), options))

    def declare_subscriber(self, *args: Any, **kwargs: Any) -> Any:
        return type("S", (), {"undeclare": lambda self: None})()


def _fake_federation(
    statuses: dict[str, dict[str, Any]], before: dict[str, dict[str, Any]] | None = None
) -> type:
    """A federation whose agents report ``statuses`` (``before`` until ctl has put)."""

    class Fed:
        count = 0  # as Federation's: statuses taken (every one is in from the start)

        def __init__(self, session: Any, federation: str) -> None:
            self.session = session

        def snapshot(self) -> dict[str, dict[str, Any]]:
            if before is not None and not getattr(self.session, "puts", None):
                return before
            return statuses

        def ages(self) -> dict[str, float]:
            return {a: 0.1 for a in statuses}

        def discover(self, agents: frozenset[str] | None, timeout: float) -> None:
            pass  # every status is in

        def close(self) -> None:
            pass

    return Fed


class _StatusFeed:
    """A session whose status subscriber the test feeds by hand."""

    def __init__(self) -> None:
        self.deliver: Any = None

    def declare_subscriber(self, key: str, handler: Any) -> Any:
        self.deliver = handler.callback
        return type("S", (), {"undeclare": lambda self: None})()

    def status(self, agent: str, after: float) -> threading.Timer:
        payload = json.dumps({"agent": agent}).encode()
        sample = SimpleNamespace(
            key_expr=f"fedlab/default/{agent}/status",
            payload=SimpleNamespace(to_bytes=lambda: payload),
        )
        timer = threading.Timer(after, lambda: self.deliver(sample))
        timer.start()
        return timer


def test_ctl_discovers_until_every_participant_has_spoken_and_no_longer() -> None:
    feed = _StatusFeed()
    fed = control.Federation(feed, "default")
    try:
        timer = feed.status("lab/a", 0.1)
        began = time.monotonic()
        fed.discover(frozenset({"lab/a"}), 10.0)  # the participant's status ends it
        assert time.monotonic() - began < 5.0 and "lab/a" in fed.snapshot()
        timer.join()
        began = time.monotonic()
        fed.discover(frozenset({"lab/a", "lab/b"}), 0.3)  # one missing: the whole time
        assert time.monotonic() - began >= 0.3
        began = time.monotonic()
        fed.discover(None, 0.3)  # anyone out there: the whole time
        assert time.monotonic() - began >= 0.3
    finally:
        fed.close()


def test_ctl_sends_an_abort_urgently_and_again_until_confirmed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import zenoh

    monkeypatch.setattr(control, "Federation", _fake_federation({"lab/a": {"mode": "running"}}))
    session = _Recorder()
    result = control.issue(session, "abort", wait=1.8, discover=0.05)
    aborts = [p for p in session.puts if p[1]["command"] == "abort"]
    # Three at once, then every 0.5 s: two more by 1.3 s, with 0.5 s to spare for a
    # stall of this process (a third resend may come at 1.5 s).
    assert not result.ok and len(aborts) >= 3 + 2
    assert all(p[1]["participants"] is None for p in aborts)  # an abort is for everyone
    for _, _, options in aborts:
        assert options["priority"] == zenoh.Priority.REAL_TIME
        assert options["congestion_control"] == zenoh.CongestionControl.BLOCK


def test_ctl_freezes_and_resumes_at_an_instant_announced_ahead_on_the_runs_reference(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    statuses: dict[str, dict[str, Any]] = {
        "lab/a": {"mode": "running", "role": "leader", "reference": "lab/a"},
        "lab/b": {
            "mode": "running", "role": "follower", "reference": "lab/a",
            "peers": {"lab/a": {"delay": 0.040}},
        },
    }  # fmt: skip
    monkeypatch.setattr(control, "Federation", _fake_federation(statuses))
    synced: list[AgentId] = []

    def reference_sync(
        session: Any, federation: str, ref: AgentId, clock: Any
    ) -> tuple[float, float]:
        synced.append(ref)
        return 100.0, 0.001  # the reference's clock now; ctl 1 ms from it

    monkeypatch.setattr(control, "reference_sync", reference_sync)
    heard = ["lab/a", "lab/b"]  # who takes a resume when it comes

    class Session(_Recorder):
        def put(self, key: str, payload: str, **options: Any) -> None:
            super().put(key, payload, **options)
            mode = {"resume": "running", "freeze": "frozen"}.get(self.puts[-1][1]["command"])
            for agent in heard if mode == "running" else list(statuses):
                statuses[agent]["mode"] = mode or statuses[agent]["mode"]

    session = Session()
    lines: list[str] = []
    # A freeze at an instant ahead: the least that reaches lab/b (40 ms from the
    # reference, ctl 1 ms from it) with margin, on the participants' reference.
    result = control.issue(session, "freeze", wait=0.5, discover=0.0, progress=lines.append)
    (command,) = {p[1]["seq"]: p[1] for p in session.puts}.values()  # copies of one command
    lead = 0.25 + 2 * 0.041
    assert command["command"] == "freeze" and command["issued_at"] == 100.0
    assert command["at"] == pytest.approx(100.0 + lead)
    assert synced == [AgentId("lab", "a")] and result.ok
    assert any("slowest path: to lab/b, 41.0 ms one way" in line for line in lines), lines
    # --in says how far ahead.
    session.puts.clear()
    control.issue(session, "freeze", start_in=2.0, wait=0.5, discover=0.0)
    assert {p[1]["at"] for p in session.puts} == {102.0}
    # A resume too, at an instant ahead.
    session.puts.clear()
    result = control.issue(session, "resume", wait=0.5, discover=0.0, progress=lines.append)
    (command,) = {p[1]["seq"]: p[1] for p in session.puts}.values()
    assert command["command"] == "resume" and command["at"] == pytest.approx(100.0 + lead)
    assert command["issued_at"] == 100.0 and result.ok
    # One that does not resume (late, say): the others are frozen again, and ctl says so.
    control.issue(session, "freeze", wait=0.5, discover=0.0)
    heard.remove("lab/b")
    session.puts.clear()
    result = control.issue(session, "resume", wait=0.5, discover=0.0, progress=lines.append)
    assert [p[1]["command"] for p in session.puts] == ["resume"] * 3 + ["freeze"] * 3
    assert result.pending == ["lab/b"] and "freeze sent to all again" in result.reasons["lab/b"]
    assert statuses["lab/a"]["mode"] == "frozen"
    # Participants on different reference clocks, one absent, or another --reference:
    # no resume sent, and why.
    session.puts.clear()
    statuses["lab/b"]["reference"] = "lab/b"
    with pytest.raises(ConfigError, match=r"2 reference clocks \(lab/a, lab/b\): not one run"):
        control.issue(session, "resume", wait=0.1, discover=0.0)
    del statuses["lab/b"]["reference"]
    with pytest.raises(ConfigError, match="resume not sent: the reference clock of lab/b is not"):
        control.issue(session, "resume", wait=0.1, discover=0.0)
    statuses["lab/b"]["reference"] = "lab/a"
    with pytest.raises(ConfigError, match="--reference lab/x, but the participants"):
        control.issue(session, "resume", reference=AgentId("lab", "x"), wait=0.1, discover=0.0)

    def silent(*args: Any, **kwargs: Any) -> tuple[float, float]:
        raise ConnectError("reference lab/a did not answer")

    monkeypatch.setattr(control, "reference_sync", silent)
    with pytest.raises(ConnectError, match="resume not sent: reference lab/a did not answer"):
        control.issue(session, "resume", wait=0.1, discover=0.0)
    assert session.puts == []
    # A freeze that cannot be timed still goes out, on receipt, and ctl says why.
    lines.clear()
    control.issue(session, "freeze", wait=0.1, discover=0.0, progress=lines.append)
    assert session.puts and {(p[1]["at"], p[1]["issued_at"]) for p in session.puts} == {
        (None, None)
    }
    assert "freeze on receipt, not at a common instant: reference lab/a did not answer" in lines


def test_a_silent_reference_is_given_up_after_a_few_queries_not_twenty() -> None:
    class Silent(_Recorder):
        queries = 0

        def declare_querier(self, *args: Any, **kwargs: Any) -> Any:
            session = self

            class Querier:
                def get(self, *args: Any, **kwargs: Any) -> None:
                    session.queries += 1  # no queryable: no reply

                def undeclare(self) -> None:
                    pass

            return Querier()

    session = Silent()
    t0 = time.monotonic()
    with pytest.raises(ConnectError, match="reference agent lab/a did not answer"):
        refclock.reference_now(session, "default", AgentId("lab", "a"), control.ExecClock())
    assert session.queries == refclock.REFERENCE_UNANSWERED == 3
    assert time.monotonic() - t0 < 5.0  # a silent leader had held ctl 20 s


def test_ctl_refuses_a_start_that_would_never_end() -> None:
    with pytest.raises(ConfigError, match="a run must end"):
        control.issue(_Recorder(), "start", discover=0.0, wait=0.1)  # no experiment, no duration


def test_ctl_aborts_a_start_a_participant_did_not_confirm_before_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    statuses = {
        "lab/a": {"mode": "armed", "run_id": "r1"},
        "lab/b": {"mode": "waiting"},  # never got it
    }
    before = {"lab/a": {"mode": "waiting"}, "lab/b": {"mode": "waiting"}}
    monkeypatch.setattr(control, "Federation", _fake_federation(statuses, before))
    monkeypatch.setattr(control, "status", lambda *a, **k: [])
    monkeypatch.setattr(control, "preflight", lambda *a, **k: [])  # passed, for this test
    monkeypatch.setattr(control, "reference_now", lambda *a, **k: 100.0)
    heard: list[str] = ["lab/a", "lab/b"]  # who takes the abort when it comes

    class Session(_Recorder):
        def put(self, key: str, payload: str, **options: Any) -> None:
            super().put(key, payload, **options)
            if self.puts[-1][1]["command"] == "abort":
                for agent in heard:
                    statuses[agent] = {"mode": "aborted"}

    session = Session()
    t0 = time.monotonic()
    result = control.issue(
        session, "start", reference=AgentId.parse("lab/a"), start_in=1.0, wait=5.0,
        discover=0.0, run_id="r1", duration=10.0,
    )  # fmt: skip
    assert time.monotonic() - t0 < 1.0  # decided before the start, not after the 5 s wait
    commands = [p[1]["command"] for p in session.puts]
    assert commands[:3] == ["start"] * 3 and "abort" in commands[3:]
    assert result.pending == ["lab/b"]
    assert "aborted before its start" in result.reasons["lab/b"]
    assert "lab/a" not in result.reasons  # it confirmed the abort
    assert "not confirmed" not in result.reasons["lab/b"]  # so did the one that missed it
    # An agent that took the start and does not confirm the abort: sent again, said.
    heard.clear()
    statuses.update({"lab/a": {"mode": "armed", "run_id": "r2"}, "lab/b": {"mode": "waiting"}})
    session.puts.clear()
    result = control.issue(
        session, "start", reference=AgentId.parse("lab/a"), start_in=1.0, wait=1.2,
        discover=0.0, run_id="r2", duration=10.0,
    )  # fmt: skip
    aborts = [p for p in session.puts if p[1]["command"] == "abort"]
    assert len(aborts) >= 3 + 1  # three at once, then again while unconfirmed
    assert "abort sent after it not confirmed" in result.reasons["lab/a"]
    # The participant that had not confirmed the start is waited for and named too: it
    # may have taken the start late, on a slow link.
    assert "abort sent after it not confirmed" in result.reasons["lab/b"]


@pytest.mark.parametrize("start_in", [0.0, 0.9])
def test_ctl_refuses_a_start_too_soon_to_abort_before_it(
    monkeypatch: pytest.MonkeyPatch, start_in: float
) -> None:
    # With --in 0 the agents present began on receipt, before ctl could find one missing.
    monkeypatch.setattr(control, "Federation", _fake_federation({"lab/a": {"mode": "waiting"}}))
    session = _Recorder()
    with pytest.raises(ConfigError, match="at least 1 s ahead"):
        control.issue(session, "start", start_in=start_in, discover=0.0, duration=10.0)
    assert session.puts == []


def test_a_plain_link_to_another_hosts_router_needs_open() -> None:
    """Nothing proves who answers a plain link: what it sends would enter this lab."""
    result = fedlab("router", "--lab", "rome", "-l", "tcp/127.0.0.1:0", "-e", "tcp/192.0.2.7:7447")
    assert result.returncode == 2
    assert "tcp/192.0.2.7:7447 is a plain link to another host" in result.stderr


def test_access_control_that_allows_all_is_no_guard_for_a_plain_link(tmp_path: Path) -> None:
    # Enabled with default allow and no rule: the link carried anything, as with none.
    path = tmp_path / "r.json5"
    path.write_text(
        '{mode: "router", metadata: {lab: "rome"}, listen: {endpoints: ["tcp/127.0.0.1:0"]},'
        ' connect: {endpoints: ["tcp/192.0.2.7:7447"]},'
        ' access_control: {enabled: true, default_permission: "allow"}}'
    )
    with pytest.raises(ConfigError, match=r"tcp/192\.0\.2\.7:7447 is a plain link to another"):
        load_router_config(ZenohOptions(config=path), None)


def test_ctl_refuses_a_run_id_an_agent_reports_before_sending_anything(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Each agent refuses to record over a run id it recorded, and that refusal aborts
    the start for all: ctl refuses a reported id first, naming who reported it."""
    statuses = {"lab/a": {"mode": "done", "run_id": "r1"}, "lab/b": {"mode": "waiting"}}
    monkeypatch.setattr(control, "Federation", _fake_federation(statuses))
    monkeypatch.setattr(control, "status", lambda *a, **k: [])
    monkeypatch.setattr(control, "preflight", lambda *a, **k: [])
    monkeypatch.setattr(control, "reference_now", lambda *a, **k: 100.0)
    session = _Recorder()
    with pytest.raises(ConfigError, match=r"--run-id r1: lab/a reported it"):
        control.issue(
            session, "start", reference=AgentId.parse("lab/a"), start_in=1.0, wait=0.1,
            discover=0.0, run_id="r1", duration=10.0,
        )  # fmt: skip
    assert session.puts == []  # nothing sent
    # A default id (to the second) that an agent reported gets a suffix.
    monkeypatch.setattr(control, "make_run_id", lambda experiment: "run-20261124T220000Z")
    statuses["lab/b"] = {"mode": "done", "run_id": "run-20261124T220000Z"}
    monkeypatch.setattr(control, "confirm", lambda *a, **k: {})
    control.issue(
        session, "start", reference=AgentId.parse("lab/a"), start_in=1.0, wait=0.1,
        discover=0.0, duration=10.0, force=True,
    )  # fmt: skip
    assert session.puts[0][1]["run_id"] == "run-20261124T220000Z-2"
    # The start is for the agents preflighted and awaited only.
    assert session.puts[0][1]["participants"] == ["lab/a", "lab/b"]

"""The command line: help with an example on every command, version, clear config errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from federation.cli import build_parser, main
from federation.fleet.launch import free_port
from federation.runtime.router import load_router_config
from schemas.config import ConfigError, ZenohOptions

ROOT = Path(__file__).resolve().parents[3]
COMMANDS = sorted(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]


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


def test_bad_flag_value_names_the_field() -> None:
    result = fedlab("agent", "--role", "leader", "--lab", "Kiruna", "--name", "knatte")
    assert result.returncode == 2
    assert "field 'lab'" in result.stderr and "lowercase" in result.stderr


def test_follower_needs_follow() -> None:
    result = fedlab("agent", "--role", "follower", "--lab", "rome", "--name", "p")
    assert result.returncode == 2
    assert "follow" in result.stderr


def test_bad_endpoint_is_refused() -> None:
    result = fedlab("router", "--lab", "kiruna", "-l", "nowhere")
    assert result.returncode == 2
    assert "nowhere" in result.stderr and "PROTOCOL/ADDRESS" in result.stderr


def test_bad_cfg_key_is_refused() -> None:
    result = fedlab("router", "--lab", "kiruna", "-l", "tcp/127.0.0.1:9", "--cfg", "no/such/key:1")
    assert result.returncode == 2
    assert "no/such/key" in result.stderr


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


def test_router_from_shipped_file_runs_and_stops_on_sigterm(tmp_path: Path) -> None:
    path = ROOT / "deploy" / "routers" / "kiruna.json5"
    listen = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "federation", "router", "-c", str(path), "-l", listen],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        time.sleep(2.0)
        assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
        os.kill(proc.pid, signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, out
    assert "router kiruna up" in out and listen in out


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_agent_waiting_for_its_router_stops_cleanly(sig: int) -> None:
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "federation",
            "agent",
            "--role",
            "leader",
            "--lab",
            "kiruna",
            "--name",
            "knatte",
            "-e",
            nowhere,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        time.sleep(4.5)  # start-up, then 2 s of waiting before the first note
        assert proc.poll() is None, "an agent keeps waiting for its router"
        os.kill(proc.pid, sig)
        out, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, out
    assert "waiting for the router" in out

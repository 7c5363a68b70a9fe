"""``fedlab ctl admit LAB/NAME`` on the command line (federation/cli/ctl.py): which
actions name agents, and preflight's table showing who waits to be admitted."""

from __future__ import annotations

import argparse
import threading
from typing import Any

import pytest
from rich.console import Console

from federation import cli
from federation.cli import main
from federation.cli.ctl import preflight_table
from federation.core.preflight import preflight


def _no_session(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    opened: list[str] = []

    def open_session(args: argparse.Namespace, stop: threading.Event) -> Any:
        opened.append(args.action)
        return None

    monkeypatch.setattr(cli.command_module("ctl"), "open_session", open_session)
    return opened


@pytest.mark.parametrize(
    ("argv", "why"),
    [
        (["ctl", "admit"], "admit names the agents to admit"),
        (["ctl", "start", "rome/p"], "start names no agents (only admit and handback do)"),
        (["ctl", "abort", "rome/p"], "abort names no agents"),
        (["ctl", "handback"], "handback names one leader: fedlab ctl handback LAB/NAME"),
        (["ctl", "handback", "rome/p", "kiruna/k"], "handback names one leader"),
    ],
)
def test_only_admit_names_agents_and_it_must(
    argv: list[str], why: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    opened = _no_session(monkeypatch)
    assert main([*argv, "-e", "tcp/127.0.0.1:9"]) == 2
    out = capsys.readouterr()
    assert why in out.out + out.err
    assert opened == []  # refused before any session is opened


def test_an_agent_name_that_is_not_lab_slash_name_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _no_session(monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        main(["ctl", "admit", "not-an-agent", "-e", "tcp/127.0.0.1:9"])
    assert exit_info.value.code == 2


def test_preflight_s_table_says_who_waits_to_be_admitted() -> None:
    statuses = {
        "rome/p": {"mode": "waiting", "admit_run": "r1", "ready": {}},
        "kiruna/k": {"mode": "running", "ready": {}},
    }
    rows = preflight(["rome/p", "kiruna/k"], statuses, {"rome/p": 0.1, "kiruna/k": 0.1})
    console = Console(record=True, width=250)
    console.print(preflight_table(rows, "t"))
    text = console.export_text()
    admitted = next(line for line in text.splitlines() if "rome/p" in line)
    assert "waiting: to be admitted to r1 (ctl admit)" in admitted
    running = next(line for line in text.splitlines() if "kiruna/k" in line)
    assert "admitted" not in running


def test_a_handback_is_confirmed_by_the_leader_holding_a_newer_epoch() -> None:
    from federation.runtime.handback import holds_role

    held = {"claim": {"kind": "leader", "holding": True, "epoch": 3}}
    assert holds_role(held) == 3 and holds_role(held, above=2) == 3
    assert holds_role(held, above=3) is None  # the epoch it held before: not handed back
    assert holds_role({"claim": {"holding": False, "epoch": 4}}) is None
    assert holds_role({"claim": None}) is None and holds_role(None) is None

"""federation/testbed/deployment.py's pure parts: the testbed's federation file, the
generated files it gives (their addresses, lab link and agents' settings), and the
readiness a status line states. Nothing here builds a namespace."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from federation.testbed import ADDR
from federation.testbed.deployment import (
    AGENTS,
    PORT,
    federation_toml,
    generate,
    locked_and_recording,
    toml_inline,
)
from schemas.federation import load_federation


def test_inline_settings_are_toml_of_their_own_types() -> None:
    text = toml_inline({"sync_window": 2.0, "seed": 3, "four_timestamps": True, "p": 'a"b'})
    assert tomllib.loads(f"x = {text}")["x"] == {
        "sync_window": 2.0, "seed": 3, "four_timestamps": True, "p": 'a"b',
    }  # fmt: skip
    assert toml_inline({}) == "{}"


@pytest.mark.parametrize(
    ("value", "error"), [(float("nan"), ValueError), (float("inf"), ValueError), ([1], TypeError)]
)
def test_a_setting_toml_cannot_say_is_refused_naming_it(value: object, error: type) -> None:
    with pytest.raises(error, match="'clock_offset'"):
        toml_inline({"clock_offset": value})


def test_settings_for_an_agent_not_in_the_federation_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\['donald'\].*knatte"):
        federation_toml(tmp_path, {"donald": {"sync_window": 2.0}})


def test_the_federation_names_the_testbeds_addresses_and_each_agents_settings(
    tmp_path: Path,
) -> None:
    source = tmp_path / "federation.toml"
    settings = {"pinocchio": {"clock_offset": 26.42, "status_period": 0.5}}
    source.write_text(federation_toml(tmp_path / "runs", settings))
    fed = load_federation(source)
    kiruna, rome = fed.labs["kiruna"], fed.labs["rome"]
    assert kiruna.endpoint == f"tls/{ADDR.kiruna}:{PORT}" and kiruna.auth == "certificate"
    assert rome.dial == ["kiruna"] and rome.auth == "password"
    for name, (lab, role) in AGENTS.items():
        agent = fed.labs[lab].agents[name]
        assert agent.role == role and agent.runs_dir == str(tmp_path / "runs" / name)
    assert fed.labs["rome"].agents["pinocchio"].follow == "kiruna/knatte"
    assert fed.labs["rome"].agents["pinocchio"].settings == settings["pinocchio"]
    assert fed.labs["kiruna"].agents["knatte"].settings == {}
    assert "evil" in kiruna.agents


def test_generated_files_dial_kiruna_over_quic_and_carry_the_settings(tmp_path: Path) -> None:
    dep = generate(tmp_path, federation_toml(tmp_path / "runs", {"knatte": {"status_period": 0.5}}))
    assert dep.binds("rome") == [(tmp_path / "fed" / "rome", tmp_path / "root")]
    assert dep.installed("agents", "knatte.toml") == str(
        tmp_path / "root" / "agents" / "knatte.toml"
    )
    assert dep.router_config("rome")["connect"]["endpoints"] == [
        f"quic/{ADDR.kiruna}:{PORT}?mixed_rel=1"
    ]
    assert (
        f"quic/{ADDR.kiruna}:{PORT}?mixed_rel=1"
        in dep.router_config("kiruna")["listen"]["endpoints"]
    )
    knatte = tomllib.loads((tmp_path / "fed" / "kiruna" / "agents" / "knatte.toml").read_text())
    assert knatte["status_period"] == 0.5 and knatte["wait_start"] is True


@pytest.mark.parametrize(
    ("line", "ready"),
    [
        (None, False),
        ({}, False),
        ({"ready": {"reference_locked": True, "recording": True}}, True),
        ({"ready": {"recording": True}}, True),  # an agent that is its own reference
        ({"ready": {"reference_locked": False, "recording": True}}, False),
        ({"ready": {"reference_locked": True, "recording": False}}, False),
    ],
)
def test_ready_means_locked_and_recording(line: dict[str, object] | None, ready: bool) -> None:
    assert locked_and_recording(line) is ready

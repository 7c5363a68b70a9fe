"""``fedlab bridge udp``'s settings (:mod:`schemas.bridge`) and its flags."""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from federation.cli import bridge as bridge_cli
from federation.cli.common import Formatter
from federation.core.estimators import DEFAULT_ESTIMATOR
from federation.core.keys import AgentId
from schemas.bridge import UdpBridgeConfig, format_address, parse_address
from schemas.config import ConfigError, validate

REQUIRED = ["--as", "rome/legacy", "--listen", "127.0.0.1:9000", "--peer", "[::1]:9001"]


def config(**overrides: Any) -> UdpBridgeConfig:
    settings: dict[str, Any] = {
        "agent": "rome/legacy",
        "listen": "127.0.0.1:9000",
        "peer": "127.0.0.1:9001",
        "follow": "kiruna/knatte",
    }
    return validate(UdpBridgeConfig, settings | overrides, "command line")


def parse(*flags: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="fedlab", formatter_class=Formatter)
    bridge_cli.add(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["bridge", "udp", *flags])


def test_parse_address() -> None:
    assert parse_address("127.0.0.1:9000", "--peer") == ("127.0.0.1", 9000)
    assert parse_address("[::1]:9000", "--peer") == ("::1", 9000)
    for bad in ("9000", "host:", "host:x", ":9000", "host:70000"):
        with pytest.raises(ConfigError, match="HOST:PORT"):
            parse_address(bad, "--peer")


def test_format_address_inverts_parse_address() -> None:
    for text in ("127.0.0.1:9000", "[::1]:9000", "example.org:0"):
        assert format_address(parse_address(text)) == text


def test_bridge_config_refuses_bad_values() -> None:
    with pytest.raises(ConfigError, match="sync_period"):
        config(sync_period=0.0)
    with pytest.raises(ConfigError, match="cannot follow itself"):
        config(follow="rome/legacy")


@pytest.mark.parametrize(
    ("field", "value", "reason"),
    [
        ("sync_timeout", -1.0, "greater than 0"),
        ("sync_window", float("inf"), "finite"),
        ("legacy_timeout", float("nan"), "finite"),
        ("status_period", 0.0, "greater than 0"),
        ("duration", 0.0, "greater than 0"),
        ("estimator", "mode", "unknown estimator"),
        ("federation", "Big Lab", "invalid federation name"),
        ("agent", "legacy", "expected LAB/NAME"),
        ("follow", "kiruna/", "invalid agent name"),
        ("listen", "9000", "HOST:PORT"),
        ("peer", "host:x", "HOST:PORT"),
        ("role", "member", "'leader' or 'follower'"),
        ("request_rate_limit", 0.0, "greater than 0"),
        ("request_rate_limit", float("inf"), "finite"),
        ("request_burst", 0, "greater than 0"),
        ("request_burst", 2.5, "valid integer"),
        ("request_port", 0, "greater than or equal to 1"),
        ("request_port", 65536, "less than or equal to 65535"),
        ("colour", "red", "unknown field"),
    ],
)
def test_a_bad_value_fails_naming_the_field(field: str, value: Any, reason: str) -> None:
    with pytest.raises(ConfigError) as error:
        config(**{field: value})
    message = str(error.value)
    assert message.startswith(f"command line: field '{field}'") and reason in message, message


def test_defaults_and_parsed_names() -> None:
    cfg = config(follow=None, peer="[::1]:9001")
    assert (cfg.sync_period, cfg.sync_timeout, cfg.legacy_timeout) == (0.1, 0.5, 2.0)
    assert cfg.estimator == DEFAULT_ESTIMATOR and cfg.role == "follower"
    assert cfg.me == AgentId("rome", "legacy") and cfg.followed is None
    assert cfg.listen_address == ("127.0.0.1", 9000) and cfg.peer_address == ("::1", 9001)
    assert cfg.peer_text == "[::1]:9001"
    # Five times the paper's 10 Hz requests; a burst of two seconds' worth; any port.
    assert (cfg.request_rate_limit, cfg.request_burst, cfg.request_port) == (50.0, 20, None)


def test_flags_become_the_config() -> None:
    cfg = bridge_cli.bridge_config(
        parse(*REQUIRED, "--follow", "kiruna/knatte", "--sync-period", "0.2",
              "--estimator", "median", "--duration", "5")
    )  # fmt: skip
    assert cfg == config(peer="[::1]:9001", sync_period=0.2, estimator="median", duration=5.0)
    assert bridge_cli.bridge_config(parse(*REQUIRED)).follow is None


def test_a_bad_flag_fails_naming_the_field() -> None:
    with pytest.raises(ConfigError, match="field 'sync_period'"):
        bridge_cli.bridge_config(parse(*REQUIRED, "--sync-period", "0"))


def test_the_request_flags_become_the_config() -> None:
    flags = ["--request-port", "9001", "--request-rate-limit", "12.5", "--request-burst", "4"]
    cfg = bridge_cli.bridge_config(parse(*REQUIRED, *flags))
    assert (cfg.request_port, cfg.request_rate_limit, cfg.request_burst) == (9001, 12.5, 4)
    for flag, value, field in [
        ("--request-rate-limit", "0", "request_rate_limit"),
        ("--request-burst", "-1", "request_burst"),
        ("--request-port", "70000", "request_port"),
    ]:
        with pytest.raises(ConfigError, match=f"command line: field '{field}'"):
            bridge_cli.bridge_config(parse(*REQUIRED, flag, value))


@pytest.mark.parametrize(
    "argv",
    [
        ["bridge", "udp", *REQUIRED],
        ["bridge", "ros2", "--as", "rome/legacy", "--odom", "/rover/odom"],
    ],
)
def test_a_bridge_speaking_as_an_agent_under_another_identity_is_refused(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """Identity = name for the agent a bridge speaks for, as for ``fedlab agent``: refused
    (exit 2) before any socket or session, naming both names."""
    from federation import cli

    other = ["--cfg", 'transport/auth/usrpwd/user:"rome/other"', "-e", "tcp/127.0.0.1:9"]
    assert cli.main([*argv, *other]) == 2
    err = capsys.readouterr().err
    assert "the user name is 'rome/other' but this agent is rome/legacy" in err


@pytest.mark.parametrize(
    ("overrides", "said"),
    [
        ({"peer": "127.0.0.1:9000"}, "own listen address"),
        ({"legacy_timeout": 0.5}, "legacy_timeout 0.5 s must exceed"),
    ],
)
def test_a_bridge_that_would_answer_itself_or_lose_its_agent_is_refused(
    overrides: dict[str, Any], said: str
) -> None:
    with pytest.raises(ConfigError, match=said):
        config(listen="127.0.0.1:9000", **overrides)

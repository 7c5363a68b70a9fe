"""Configuration loading (schemas/config.py): files written to tmp_path."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from federation.core.keys import AgentId
from schemas.config import (
    AgentConfig,
    ConfigError,
    RouterConfig,
    ZenohOptions,
    load_model,
    validate,
)
from schemas.platform import PlatformConfig

LEADER_TOML = """\
lab = "kiruna"
name = "knatte"
role = "leader"
"""

FOLLOWER_TOML = """\
federation = "esa"
lab = "rome"
name = "pinocchio"
role = "follower"
follow = "kiruna/knatte"
sync_with = ["kiruna/knatte"]
sync_period = 0.1
sync_timeout = 0.5
sync_window = 10.0
estimator = "median"
pose_rate = 20.0
status_period = 1.0
clock_offset = -30.88
clock_drift_ppm = 12.5
duration = 90.0
status_json = "runs/rome.jsonl"
platform = "kinematic"
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def toml_with(**fields: object) -> str:
    """The leader's TOML with extra or replacing fields, values given as TOML text."""
    lines = dict(line.split(" = ", 1) for line in LEADER_TOML.splitlines())
    lines.update({k: str(v) for k, v in fields.items()})
    return "".join(f"{k} = {v}\n" for k, v in lines.items())


def load_error(path: Path, model: type = AgentConfig) -> str:
    with pytest.raises(ConfigError) as info:
        load_model(model, path)
    return str(info.value)


# --------------------------------------------------------------- good files


def test_load_minimal_toml_with_defaults(tmp_path: Path) -> None:
    config = load_model(AgentConfig, write(tmp_path, "leader.toml", LEADER_TOML))
    assert isinstance(config, AgentConfig)
    assert config.federation == "default"
    assert config.agent == AgentId("kiruna", "knatte")
    assert config.role == "leader"
    assert config.follow is None
    assert config.sync_with == []
    assert config.sync_period == 0.1
    assert config.sync_timeout == 0.5
    assert config.sync_window == 10.0
    assert config.estimator == "clockfilter"
    assert config.pose_rate == 20.0
    assert config.clock_offset == 0.0
    assert config.duration is None
    assert config.platform == "kinematic"


def test_load_full_toml(tmp_path: Path) -> None:
    config = load_model(AgentConfig, write(tmp_path, "rome.toml", FOLLOWER_TOML))
    assert config.federation == "esa"
    assert config.agent == AgentId("rome", "pinocchio")
    assert config.follow == "kiruna/knatte"
    assert config.sync_with == ["kiruna/knatte"]
    assert config.estimator == "median"
    assert config.clock_offset == -30.88
    assert config.clock_drift_ppm == 12.5
    assert config.duration == 90.0
    assert config.status_json == Path("runs/rome.jsonl")


def test_load_json(tmp_path: Path) -> None:
    data = {"lab": "rome", "name": "pinocchio", "role": "follower", "follow": "kiruna/knatte"}
    config = load_model(AgentConfig, write(tmp_path, "rome.json", json.dumps(data)))
    assert config.role == "follower"
    assert config.follow == "kiruna/knatte"


def test_load_accepts_str_path(tmp_path: Path) -> None:
    path = write(tmp_path, "leader.toml", LEADER_TOML)
    assert load_model(AgentConfig, str(path)).name == "knatte"


def test_int_accepted_for_float_field(tmp_path: Path) -> None:
    config = load_model(AgentConfig, write(tmp_path, "a.toml", toml_with(sync_period=1)))
    assert config.sync_period == 1.0


def test_config_is_frozen(tmp_path: Path) -> None:
    config = load_model(AgentConfig, write(tmp_path, "a.toml", LEADER_TOML))
    with pytest.raises(ValueError):
        config.sync_period = 5.0  # type: ignore[misc]


def test_load_router_and_platform(tmp_path: Path) -> None:
    router = load_model(
        RouterConfig,
        write(
            tmp_path,
            "kiruna.toml",
            'lab = "kiruna"\nlisten = ["tcp/0.0.0.0:7447"]\nconnect = ["tcp/rome.example:7447"]\n',
        ),
    )
    assert router.listen == ["tcp/0.0.0.0:7447"]
    assert router.connect == ["tcp/rome.example:7447"]
    platform = load_model(
        PlatformConfig,
        write(tmp_path, "knatte.json", json.dumps({"name": "knatte", "mass": 10, "inertia": 0.16})),
    )
    assert platform.mass == 10.0
    assert platform.inertia == 0.16
    assert platform.max_rate == 0.5


# ---------------------------------------------------------------- bad values


@pytest.mark.parametrize(
    ("fields", "field", "reason"),
    [
        pytest.param({"sync_period": -1}, "sync_period", "greater than 0", id="negative period"),
        pytest.param({"sync_period": 0}, "sync_period", "greater than 0", id="zero period"),
        pytest.param({"sync_period": 11}, "sync_period", "less than or equal", id="long period"),
        pytest.param({"sync_period": '"fast"'}, "sync_period", "number", id="wrong type"),
        pytest.param({"sync_timeout": -0.5}, "sync_timeout", "greater than 0", id="timeout"),
        pytest.param({"sync_window": 0}, "sync_window", "greater than 0", id="window"),
        pytest.param({"pose_rate": 2000}, "pose_rate", "less than or equal", id="pose rate"),
        pytest.param({"status_period": 0}, "status_period", "greater than 0", id="status"),
        pytest.param({"duration": -5}, "duration", "greater than 0", id="duration"),
        pytest.param({"clock_offset": "nan"}, "clock_offset", "finite", id="nan offset"),
        pytest.param({"clock_offset": "inf"}, "clock_offset", "finite", id="inf offset"),
        pytest.param({"clock_drift_ppm": 1e5}, "clock_drift_ppm", "less than", id="drift"),
        pytest.param({"estimator": '"max"'}, "estimator", "'mean' or 'median'", id="statistic"),
        pytest.param({"role": '"boss"'}, "role", "'member' or 'stand-in'", id="role"),
        pytest.param({"platform": '"rigid"'}, "platform", "kinematic", id="platform"),
        pytest.param({"lab": '"Kiruna"'}, "lab", "invalid lab name", id="uppercase lab"),
        pytest.param({"lab": '"kiruna/x"'}, "lab", "invalid lab name", id="slash lab"),
        pytest.param({"lab": '"*"'}, "lab", "invalid lab name", id="star lab"),
        pytest.param({"lab": '""'}, "lab", "invalid lab name", id="empty lab"),
        pytest.param({"name": '"kn atte"'}, "name", "invalid agent name", id="agent name"),
        pytest.param({"federation": '"$fed"'}, "federation", "invalid federation", id="fed"),
        pytest.param({"follow": '"knatte"'}, "follow", "LAB/NAME", id="follow no slash"),
        pytest.param({"sync_with": '["kiruna/knatte", "x"]'}, "sync_with.1", "LAB/NAME", id="w"),
        pytest.param({"sync_with": '"kiruna/knatte"'}, "sync_with", "list", id="not a list"),
        pytest.param({"sync_perod": 0.1}, "sync_perod", "unknown field", id="unknown key"),
    ],
)
def test_bad_value_names_file_and_field(
    tmp_path: Path, fields: dict[str, object], field: str, reason: str
) -> None:
    path = write(tmp_path, "rome.toml", toml_with(**fields))
    message = load_error(path)
    assert str(path) in message
    assert f"field '{field}'" in message
    assert reason in message


def test_bad_value_message_format(tmp_path: Path) -> None:
    path = write(tmp_path, "rome.toml", toml_with(sync_period=-1))
    assert load_error(path) == f"{path}: field 'sync_period': Input should be greater than 0"


def test_missing_required_field(tmp_path: Path) -> None:
    path = write(tmp_path, "a.toml", 'lab = "kiruna"\nrole = "leader"\n')
    message = load_error(path)
    assert f"{path}: field 'name': Field required" in message


def test_every_problem_on_its_own_line(tmp_path: Path) -> None:
    path = write(tmp_path, "a.toml", toml_with(sync_period=-1, pose_rate=0, colour='"red"'))
    lines = load_error(path).splitlines()
    assert len(lines) == 3
    assert all(line.startswith(f"{path}: field '") for line in lines)
    fields = {line.split("'")[1] for line in lines}
    assert fields == {"sync_period", "pose_rate", "colour"}


def test_follower_without_follow(tmp_path: Path) -> None:
    path = write(tmp_path, "rome.toml", toml_with(role='"follower"'))
    message = load_error(path)
    assert str(path) in message
    assert "follow" in message
    assert "a follower needs 'follow'" in message


def test_agent_cannot_follow_itself(tmp_path: Path) -> None:
    path = write(tmp_path, "a.toml", toml_with(role='"follower"', follow='"kiruna/knatte"'))
    message = load_error(path)
    assert str(path) in message
    assert "cannot follow itself" in message


def test_leader_may_name_follow(tmp_path: Path) -> None:
    # Only followers need it; a leader with one is accepted.
    config = load_model(AgentConfig, write(tmp_path, "a.toml", toml_with(follow='"rome/pino"')))
    assert config.follow == "rome/pino"


def test_bad_value_in_json(tmp_path: Path) -> None:
    data = {"lab": "kiruna", "name": "knatte", "role": "leader", "sync_period": -1}
    path = write(tmp_path, "a.json", json.dumps(data))
    message = load_error(path)
    assert str(path) in message
    assert "field 'sync_period'" in message


def test_bad_endpoint(tmp_path: Path) -> None:
    path = write(tmp_path, "r.toml", 'lab = "kiruna"\nlisten = ["tcp/0.0.0.0:7447", "7447"]\n')
    message = load_error(path, RouterConfig)
    assert str(path) in message
    assert "field 'listen.1'" in message
    assert "PROTOCOL/ADDRESS" in message


@pytest.mark.parametrize("endpoint", ["tcp", "/127.0.0.1:7447", "tcp/", ""])
def test_zenoh_options_bad_endpoints(endpoint: str) -> None:
    with pytest.raises(ValueError, match="PROTOCOL/ADDRESS"):
        ZenohOptions(connect=[endpoint])


def test_an_endpoint_without_its_port_is_refused_as_it_is_parsed(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as error:
        validate(ZenohOptions, {"connect": ["tcp/127.0.0.1"]}, "command line")
    assert str(error.value) == (
        "command line: field 'connect.0': Value error, invalid endpoint 'tcp/127.0.0.1': "
        "no port: write tcp/127.0.0.1:PORT, e.g. tcp/127.0.0.1:7447"
    )
    path = write(tmp_path, "r.toml", 'lab = "kiruna"\nconnect = ["tls/kiruna.example.org"]\n')
    message = load_error(path, RouterConfig)
    assert f"{path}: field 'connect.0'" in message and "no port" in message


def test_zenoh_options_good() -> None:
    options = ZenohOptions(mode="client", connect=["tcp/127.0.0.1:7447"])
    assert options.connect == ["tcp/127.0.0.1:7447"]
    assert options.listen == []


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"name": "knatte", "mass": 0, "inertia": 0.16}, "mass"),
        ({"name": "knatte", "mass": 10, "inertia": -1}, "inertia"),
        ({"name": "KNATTE", "mass": 10, "inertia": 0.16}, "name"),
        ({"name": "knatte", "mass": 10, "inertia": 0.16, "max_rate": 0}, "max_rate"),
    ],
)
def test_bad_platform(tmp_path: Path, data: dict[str, object], field: str) -> None:
    path = write(tmp_path, "p.json", json.dumps(data))
    message = load_error(path, PlatformConfig)
    assert str(path) in message
    assert f"field '{field}'" in message


# ---------------------------------------------------------------- bad files


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.toml"
    message = load_error(path)
    assert str(path) in message
    assert "cannot read" in message
    assert "No such file" in message


def test_directory_instead_of_file(tmp_path: Path) -> None:
    path = tmp_path / "dir.toml"
    path.mkdir()
    message = load_error(path)
    assert str(path) in message
    assert "cannot read" in message


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root can read any file")
def test_unreadable_file(tmp_path: Path) -> None:
    path = write(tmp_path, "secret.toml", LEADER_TOML)
    path.chmod(0)
    try:
        message = load_error(path)
    finally:
        path.chmod(0o600)
    assert str(path) in message
    assert "cannot read" in message


def test_file_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('lab = "kiruna"\nname = "knatte"\nrole = "leader" # Malmö\n'.encode("latin-1"))
    message = load_error(path)
    assert str(path) in message
    assert "not UTF-8" in message


@pytest.mark.parametrize(
    "text",
    [
        'lab = "kiruna\n',  # unterminated string
        "lab = kiruna\n",  # bare word
        "lab = \nname = 1\n",
        "[[[\n",
        'lab = "a"\nlab = "b"\n',  # duplicate key
    ],
)
def test_invalid_toml(tmp_path: Path, text: str) -> None:
    path = write(tmp_path, "broken.toml", text)
    message = load_error(path)
    assert message.startswith(f"{path}: not valid TOML")


@pytest.mark.parametrize("text", ["{", "lab = 'kiruna'", "", '{"lab": }'])
def test_invalid_json(tmp_path: Path, text: str) -> None:
    path = write(tmp_path, "broken.json", text)
    message = load_error(path)
    assert message.startswith(f"{path}: not valid JSON")


@pytest.mark.parametrize("text", ["[]", '["lab"]', "42", '"kiruna"', "null"])
def test_json_top_level_not_a_table(tmp_path: Path, text: str) -> None:
    path = write(tmp_path, "list.json", text)
    message = load_error(path)
    assert str(path) in message
    assert "top level" in message


def test_toml_content_in_json_file_is_json_error(tmp_path: Path) -> None:
    path = write(tmp_path, "leader.json", LEADER_TOML)
    assert "not valid JSON" in load_error(path)


def test_empty_toml_reports_every_missing_field(tmp_path: Path) -> None:
    path = write(tmp_path, "empty.toml", "")
    message = load_error(path)
    for field in ("lab", "name", "role"):
        assert f"{path}: field '{field}': Field required" in message


def test_config_error_is_value_error() -> None:
    assert issubclass(ConfigError, ValueError)


@pytest.mark.parametrize(
    ("listen", "refused"),
    [
        ("tcp/127.0.0.1:7447", False),
        ("tcp/[::1]:7447", False),
        ("tcp/localhost:7447", False),
        ("tcp/0.0.0.0:7447", True),
        ("tcp/[::]:7447", True),
        ("udp/192.0.2.1:7447", True),
        ("tls/kiruna.example.org:7447", True),
    ],
)
def test_a_router_open_beyond_its_host_without_access_control_is_refused(
    listen: str, refused: bool
) -> None:
    from federation.runtime.router import load_router_config
    from schemas.config import ZenohOptions

    options = ZenohOptions(listen=[listen])
    if refused:
        with pytest.raises(ConfigError, match=r"field 'listen': .* no access control is on"):
            load_router_config(options, "kiruna")
        load_router_config(options, "kiruna", open_=True)  # said on purpose
        guarded = ZenohOptions(
            listen=[listen],
            cfg=["access_control/enabled:true", 'access_control/default_permission:"deny"'],
        )
        load_router_config(guarded, "kiruna")
    else:
        load_router_config(options, "kiruna")


def test_a_real_platform_waits_for_an_operators_start() -> None:
    """A deployed serial leader had started its maneuver when its service started, and
    again 2 s after every crash (Restart=on-failure)."""
    from schemas.config import AgentConfig, ConfigError, validate

    settings = {"lab": "kiruna", "name": "knatte", "role": "leader"}
    with pytest.raises(ConfigError, match="wait_start"):
        validate(AgentConfig, settings | {"platform": "serial:/dev/ttyUSB0"}, "knatte.toml")
    validate(AgentConfig, settings | {"platform": "serial:/dev/x", "wait_start": True}, "k")


def test_sync_with_and_sync_all_together_are_refused() -> None:
    from schemas.config import AgentConfig, ConfigError, validate

    settings = {"lab": "rome", "name": "p", "role": "follower", "follow": "kiruna/knatte"}
    with pytest.raises(ConfigError, match="sync_with and sync_all together"):
        validate(AgentConfig, settings | {"sync_with": ["lab/x"], "sync_all": True}, "p.toml")

"""federation.runtime.zenoh_text, on the errors Zenoh's own loader raises, and the
checks build_config makes of a config file's endpoints."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh

from federation.runtime.session import ZenohConfigError, build_config
from federation.runtime.zenoh_text import config_file_problem, without_source_location
from schemas.config import ZenohOptions

ROOT = Path(__file__).resolve().parents[3]
KIRUNA = ROOT / "deploy" / "routers" / "kiruna.json5"


def _zenoh_error(path: Path) -> str:
    with pytest.raises(Exception) as error:
        zenoh.Config.from_file(str(path))
    return str(error.value)


def test_a_misspelled_key_is_named_with_its_line_and_the_closest_key(tmp_path: Path) -> None:
    path = tmp_path / "router.json5"
    path.write_text(KIRUNA.read_text().replace("  listen:", "  lisen:", 1))
    raw = _zenoh_error(path)
    assert ".rs:" in raw  # Zenoh's own message ends with its Rust source location
    problem = config_file_problem(raw)
    assert problem.startswith("line 13, column 3: unknown field `lisen` (did you mean `listen`?)")
    assert "expected one of `id`" in problem  # Zenoh's words are kept
    assert ".rs" not in problem and "cargo" not in problem


def test_a_misspelled_value_names_the_closest_one(tmp_path: Path) -> None:
    path = tmp_path / "router.json5"
    path.write_text('{ mode: "routr" }')
    problem = config_file_problem(_zenoh_error(path))
    assert problem == (
        "line 1, column 9: unknown variant `routr` (did you mean `router`?), "
        "expected one of `router`, `peer`, `client`"
    )


def test_a_json5_syntax_error_shows_the_line_and_where_in_it(tmp_path: Path) -> None:
    path = tmp_path / "router.json5"
    path.write_text('{\n  mode: "router",,\n}')
    problem = config_file_problem(_zenoh_error(path))
    lines = problem.splitlines()
    assert lines[0].startswith("line 2, column 18: expected"), problem
    assert lines[1] == '2 |   mode: "router",,' and "^" in lines[2]
    assert ".rs" not in problem


def test_a_loaded_file_names_itself_and_the_problem(tmp_path: Path) -> None:
    path = tmp_path / "agent.json5"
    path.write_text('{ mode: "client", conect: { endpoints: [] } }')
    with pytest.raises(ZenohConfigError) as error:
        build_config(ZenohOptions(config=path), default_mode="client")
    assert str(error.value) == (
        f"{path}: not a valid Zenoh config: line 1, column 19: unknown field `conect` "
        f"(did you mean `connect`?), expected one of " + str(error.value).split("one of ", 1)[1]
    )
    assert ".rs" not in str(error.value)


def test_the_source_location_is_removed_from_nested_messages_too() -> None:
    raw = (
        "Can not create a new TCP listener bound to tcp/127.0.0.1:7460: [127.0.0.1:7460: "
        "Address already in use (os error 98) at /root/.cargo/git/checkouts/zenoh-9c5/"
        "cc83980/io/zenoh-link-commons/src/tcp.rs:61.] at /x/zenoh/src/net/runtime/mod.rs:9."
    )
    assert without_source_location(raw) == (
        "Can not create a new TCP listener bound to tcp/127.0.0.1:7460: [127.0.0.1:7460: "
        "Address already in use (os error 98)]"
    )


@pytest.mark.parametrize(
    "connect",
    ['{ endpoints: ["tcp/127.0.0.1"] }', '{ endpoints: { router: [], client: ["tcp/h"] } }'],
)
def test_an_endpoint_without_its_port_in_a_config_file_is_refused_naming_it(
    tmp_path: Path, connect: str
) -> None:
    path = tmp_path / "agent.json5"
    path.write_text(f'{{ mode: "client", connect: {connect} }}')
    with pytest.raises(ZenohConfigError) as error:
        build_config(ZenohOptions(config=path), default_mode="client")
    assert str(error.value).startswith(f"{path}: 'connect/endpoints': tcp/")
    assert ": no port: write tcp/" in str(error.value)


def test_an_endpoint_without_its_port_in_a_cfg_flag_is_refused_naming_it() -> None:
    with pytest.raises(ZenohConfigError) as error:
        build_config(
            ZenohOptions(cfg=['listen/endpoints:["tcp/127.0.0.1"]']), default_mode="router"
        )
    assert str(error.value) == (
        "--cfg: 'listen/endpoints': tcp/127.0.0.1: no port: write tcp/127.0.0.1:PORT, "
        "e.g. tcp/127.0.0.1:7447"
    )

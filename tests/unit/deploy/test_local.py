"""A federation moved onto one host (federation/deploy/local.py, ``generate --local``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from federation import cli
from federation.deploy import generate as gen
from federation.deploy.local import localize
from schemas.base import ConfigError
from schemas.federation import load_federation

EXAMPLE = Path(__file__).resolve().parents[3] / "deploy" / "federation.example.toml"
THREE = EXAMPLE.with_name("federation.three-labs.toml")


def _get(path: Path, key: str) -> object:
    return json.loads(zenoh.Config.from_file(str(path)).get_json(key))


def test_every_lab_of_the_example_moves_to_loopback_a_port_each() -> None:
    fed = localize(load_federation(EXAMPLE))
    kiruna, rome = fed.labs["kiruna"], fed.labs["rome"]
    # Both listen on 7447 in the file (on two hosts): one up for the second.
    assert kiruna.listen == ["tls/127.0.0.1:7447"] and rome.listen == ["tls/127.0.0.1:7448"]
    assert kiruna.endpoint == "tls/localhost:7447"
    assert kiruna.agents_endpoint() == "tls/localhost:7447"
    assert rome.agents_endpoint() == "tls/localhost:7448"
    assert kiruna.cert_hosts() == ["localhost", "127.0.0.1"]
    assert kiruna.agents == load_federation(EXAMPLE).labs["kiruna"].agents


def test_a_first_port_numbers_the_labs_in_file_order() -> None:
    fed = localize(load_federation(THREE), port=20000)
    assert [e.listen[0] for e in fed.labs.values()] == [
        "tls/127.0.0.1:20000", "tls/127.0.0.1:20001", "tls/127.0.0.1:20002"
    ]  # fmt: skip
    with pytest.raises(ConfigError, match="ports 65534 to 65536, past 65535"):
        localize(load_federation(THREE), port=65534)


def test_a_lab_already_on_loopback_keeps_its_endpoints(tmp_path: Path) -> None:
    source = tmp_path / "federation.toml"
    source.write_text(
        EXAMPLE.read_text()
        .replace('listen = ["tls/[::]:7447"]', 'listen = ["tls/127.0.0.1:7447"]')
        .replace("tls/kiruna.example.org:7447", "tls/localhost:7447")
        .replace("tls/kiruna-router.lab.example:7447", "tls/localhost:7447")
    )
    fed = localize(load_federation(source))
    assert fed.labs["kiruna"].listen == ["tls/127.0.0.1:7447"]
    assert fed.labs["kiruna"].hosts == ["192.0.2.10"]  # as the file has it
    assert fed.labs["rome"].listen == ["tls/127.0.0.1:7448"]  # its 7447 is kiruna's


def test_generate_local_writes_loopback_endpoints_and_matching_certificates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fed"
    args = ["deploy", "generate", str(EXAMPLE), "--out", str(out), "--local", "--port", "30000"]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert "kiruna: its router listens on tls/127.0.0.1:30000" in printed
    assert "rome: its router listens on tls/127.0.0.1:30001" in printed
    rome_router = out / "rome" / "routers" / "rome.json5"
    assert _get(rome_router, "listen/endpoints") == ["tls/127.0.0.1:30001#enable_mtls=false"]
    # Rome dials Kiruna over QUIC (pose as datagrams), on 127.0.0.1: lablink.quic_endpoint
    assert _get(rome_router, "connect/endpoints") == ["quic/127.0.0.1:30000?mixed_rel=1"]
    knatte = out / "kiruna" / "agents" / "knatte.json5"
    assert _get(knatte, "connect/endpoints") == ["tls/localhost:30000"]
    ctl = out / "rome" / "operators" / "ctl.json5"
    assert _get(ctl, "connect/endpoints") == ["tls/localhost:30001"]
    for lab in ("kiruna", "rome"):
        assert gen._sans(out / lab / "certs" / f"{lab}.pem") == {"localhost", "127.0.0.1"}


def test_port_without_local_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["deploy", "generate", str(EXAMPLE), "--out", str(tmp_path), "--port", "30000"]
    assert cli.main(args) == 2
    assert "--port moves the labs onto loopback: give --local too" in capsys.readouterr().err

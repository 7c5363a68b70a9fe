"""Which link a generated router dials another lab's over (federation/deploy/lablink.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from federation.deploy import generate as gen
from federation.deploy import lablink
from schemas.federation import FederationFile, load_federation

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "deploy" / "federation.example.toml"


def test_a_tls_endpoint_becomes_its_quic_twin_with_mixed_reliability() -> None:
    assert lablink.quic_endpoint("tls/kiruna.example.org:7447") == (
        "quic/kiruna.example.org:7447?mixed_rel=1"
    )
    assert (
        lablink.quic_endpoint("tls/[::]:7447#iface=eth0") == "quic/[::]:7447?mixed_rel=1#iface=eth0"
    )
    assert lablink.quic_endpoint("tls/localhost:7447") == "quic/127.0.0.1:7447?mixed_rel=1"
    with pytest.raises(ValueError, match="expected a tls/ endpoint"):
        lablink.quic_endpoint("tcp/127.0.0.1:7447")


def test_a_certificate_lab_is_dialled_over_quic_and_listens_on_both() -> None:
    fed = load_federation(EXAMPLE)
    kiruna = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    rome = gen.router_config(fed, "rome", gen.DEFAULT_ROOT)
    assert kiruna["listen"]["endpoints"] == ["tls/[::]:7447", "quic/[::]:7447?mixed_rel=1"]
    assert rome["connect"]["endpoints"] == ["quic/kiruna.example.org:7447?mixed_rel=1"]
    assert kiruna["transport"]["link"]["protocols"] == ["tls", "quic"]
    # Rome's own listener (password lab, dialled by nobody) stays TLS only.
    assert all(e.startswith("tls/") for e in rome["listen"]["endpoints"])
    # Agents reach their router over TLS.
    agent = gen.agent_zenoh(fed, "kiruna", "knatte", gen.DEFAULT_ROOT, None)
    assert agent["transport"]["link"]["protocols"] == ["tls"]


def test_lab_link_tls_keeps_every_link_on_tcp() -> None:
    data = load_federation(EXAMPLE).model_dump()
    fed = FederationFile.model_validate(data | {"lab_link": "tls"})
    rome = gen.router_config(fed, "rome", gen.DEFAULT_ROOT)
    kiruna = gen.router_config(fed, "kiruna", gen.DEFAULT_ROOT)
    assert rome["connect"]["endpoints"] == ["tls/kiruna.example.org:7447"]
    assert kiruna["listen"]["endpoints"] == ["tls/[::]:7447"]
    assert kiruna["transport"]["link"]["protocols"] == ["tls"]

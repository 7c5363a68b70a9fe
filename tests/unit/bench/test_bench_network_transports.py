"""The secure lab links of ``fedlab bench network`` (``tls``, ``quic``, ``quic-stream``):
the generated deployment's mutual-TLS settings on the routers, and the endpoints each
side uses. No testbed: the router arguments and the certificates only."""

from __future__ import annotations

import ipaddress
from pathlib import Path

import pytest
from cryptography import x509

from federation.bench import network
from federation.testbed import ADDR

SECURE = ("tls", "quic", "quic-stream")


def _cfg(args: list[str]) -> dict[str, str]:
    return dict(args[i + 1].split(":", 1) for i, a in enumerate(args) if a == "--cfg")


def _listen(args: list[str]) -> list[str]:
    return [args[i + 1] for i, a in enumerate(args) if a == "-l"]


@pytest.mark.parametrize("transport", SECURE)
@pytest.mark.parametrize("lab", ["kiruna", "rome"])
def test_a_secure_lab_link_shows_the_labs_certificate_with_mtls(
    transport: str, lab: str, tmp_path: Path
) -> None:
    args = network._router_args(lab, transport, ["transport/link/tx/lease:10000"], tmp_path)
    cfg = _cfg(args)
    assert cfg["transport/link/tls/root_ca_certificate"] == f'"{tmp_path / "ca.pem"}"'
    for side in ("listen", "connect"):
        assert cfg[f"transport/link/tls/{side}_certificate"] == f'"{tmp_path / lab}.pem"'
        assert cfg[f"transport/link/tls/{side}_private_key"] == f'"{tmp_path / lab}.key"'
    assert cfg["transport/link/tls/enable_mtls"] == "true"
    assert cfg["transport/link/tls/verify_name_on_connect"] == "true"
    assert args[-2:] == ["--cfg", "transport/link/tx/lease:10000"]  # the caller's, last


@pytest.mark.parametrize("transport", SECURE)
def test_agents_reach_their_router_on_loopback_and_only_the_lab_link_is_secure(
    transport: str, tmp_path: Path
) -> None:
    kiruna = network._router_args("kiruna", transport, (), tmp_path)
    rome = network._router_args("rome", transport, (), tmp_path)
    scheme = transport.split("-")[0]
    loopback, wan = _listen(kiruna)
    assert loopback == f"tcp/127.0.0.1:{network.PORT}"
    assert wan.startswith(f"{scheme}/{ADDR.kiruna}:{network.PORT}")
    assert _listen(rome) == [f"tcp/127.0.0.1:{network.PORT}"]
    dialled = rome[rome.index("-e") + 1]
    assert dialled.startswith(f"{scheme}/{ADDR.kiruna}:{network.PORT}")


def test_quic_carries_best_effort_as_datagrams_on_both_sides_and_opens_udp() -> None:
    t = network.TRANSPORTS["quic"]
    assert t["kiruna"][1].endswith("?mixed_rel=1") and t["rome"][1].endswith("?mixed_rel=1")
    assert t["ports"] == ["udp/7447"]
    assert "mixed_rel" not in " ".join(network.TRANSPORTS["quic-stream"]["rome"])
    assert network.TRANSPORTS["tls"]["ports"] == ["tcp/7447"]


def test_the_plain_transports_are_unchanged() -> None:
    args = network._router_args("kiruna", "tcp-tuned")
    assert _listen(args) == [f"tcp/0.0.0.0:{network.PORT}"]
    assert not any(a.startswith("transport/link/tls") for a in args)


def test_a_secure_transport_without_certificates_is_refused() -> None:
    with pytest.raises(ValueError, match="certificates"):
        network._router_args("rome", "quic")


def test_kiruna_certificate_names_its_testbed_address(tmp_path: Path) -> None:
    d = network.make_certs(tmp_path / "certs")
    network.make_certs(d)  # a rerun in the same folder replaces them
    cert = x509.load_pem_x509_certificate((d / "kiruna.pem").read_bytes())
    sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert ipaddress.ip_address(ADDR.kiruna) in sans.get_values_for_type(x509.IPAddress)
    assert {p.name for p in d.iterdir()} >= {"ca.pem", "kiruna.pem", "kiruna.key", "rome.pem"}

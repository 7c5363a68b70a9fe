"""``fedlab certs``: the federation CA, lab and agent certificates (no processes).

The shipped TLS router configs using them are tested with real routers in
tests/integration/test_security.py.
"""

from __future__ import annotations

import argparse
import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from federation import cli
from federation.deploy import certs


def _cn(cert: x509.Certificate) -> str:
    value = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
    return value if isinstance(value, str) else value.decode()


def _load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def test_certs_init_issue_and_refuse_to_overwrite(tmp_path: Path) -> None:
    d = tmp_path / "certs"
    with pytest.raises(certs.CertError, match="certs init"):
        certs.issue_lab(d, "kiruna")
    ca = certs.init_ca(d, "demo")
    assert (ca.cert.name, ca.key.name) == ("ca.pem", "ca.key")
    ca_cert = _load(ca.cert)
    assert _cn(ca_cert) == "demo federation CA" == ca.common_name
    assert ca_cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    with pytest.raises(certs.CertError, match="--force"):
        certs.init_ca(d, "demo")
    assert _load(ca.cert) == ca_cert  # untouched
    assert _load(certs.init_ca(d, "demo", force=True).cert) != ca_cert

    lab = certs.issue_lab(d, "kiruna")
    cert = _load(lab.cert)
    assert (lab.cert.name, lab.key.name, _cn(cert)) == ("kiruna.pem", "kiruna.key", "kiruna")
    sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(v) for v in sans.get_values_for_type(x509.DNSName)] == ["localhost"]
    assert {str(v) for v in sans.get_values_for_type(x509.IPAddress)} == {"127.0.0.1", "::1"}
    usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert set(usage) == {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH}
    assert cert.issuer == _load(d / "ca.pem").subject
    with pytest.raises(certs.CertError, match="--force"):
        certs.issue_lab(d, "kiruna")
    other = certs.issue_lab(d, "rome", ["rome.example.org", "192.0.2.7"])
    sans = _load(other.cert).extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert sans.get_values_for_type(x509.DNSName) == ["rome.example.org"]
    assert [str(v) for v in sans.get_values_for_type(x509.IPAddress)] == ["192.0.2.7"]

    agent = certs.issue_agent(d, "kiruna", "knatte")
    cert = _load(agent.cert)
    assert (agent.cert.name, _cn(cert)) == ("kiruna.knatte.pem", "kiruna/knatte")
    usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert list(usage) == [ExtendedKeyUsageOID.CLIENT_AUTH]

    for path in d.iterdir():
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode == (0o600 if path.suffix == ".key" else 0o644), (path, oct(mode))
    for bad in (lambda: certs.issue_lab(d, "Kiruna"), lambda: certs.issue_agent(d, "a", "b/c")):
        with pytest.raises(ValueError):
            bad()
    with pytest.raises(certs.CertError, match="host"):
        certs.issue_lab(d, "lund", ["bad host"])


def test_certs_command_line(tmp_path: Path) -> None:
    """``fedlab certs ...`` through the real parser."""
    d = str(tmp_path / "c")
    assert cli.main(["certs", "init", "--dir", d, "--federation", "demo"]) == 0
    assert cli.main(["certs", "init", "--dir", d]) == 2  # refuses without --force
    assert cli.main(["certs", "issue", "kiruna", "--dir", d, "--host", "kiruna.example.org"]) == 0
    assert cli.main(["certs", "issue-agent", "kiruna", "knatte", "--dir", d]) == 0
    assert cli.main(["certs", "issue", "rome", "--dir", str(tmp_path / "none")]) == 2
    assert _cn(_load(tmp_path / "c" / "kiruna.knatte.pem")) == "kiruna/knatte"
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert "Example" in (sub.choices["certs"].epilog or "")

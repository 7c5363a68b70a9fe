"""``fedlab certs``: a federation's certificate authority and its labs' certificates.

One CA per federation signs one certificate per lab router and one per agent. Lab
routers link with mutual TLS (each shows its lab certificate and checks the other's
against the CA); agents show theirs to their own lab's router, whose access control
knows them by Common Name (``cert_common_names`` in the router configs that
:mod:`federation.deploy.generate` writes, e.g. deploy/routers/tls/*.json5).
Files written to the certificate folder::

    ca.pem, ca.key                  federation CA, CN "<federation> federation CA"
    <lab>.pem, <lab>.key            lab router, CN "<lab>", SANs: the router's host names
    <lab>.<name>.pem, .key          agent <lab>/<name>, CN "<lab>/<name>" (client only)

An agent's CN is its fedlab address, ``lab/name``; Zenoh compares CNs as plain
strings, and a ``/`` in one was checked to match an ACL subject (tests/test_security.py).
Lab and agent names never contain a dot (federation.core.keys), so ``<lab>.<name>`` is an
unambiguous file name.

Keys are ECDSA P-256 in PKCS#8 PEM, written with mode 0600; certificates are X.509
v3 and always carry a Common Name (a certificate without one broke Zenoh's TLS links
in 1.7.2, zenoh issue 2400).

The functions here do the work and print nothing; ``fedlab certs``
(:mod:`federation.cli.certs`) parses the flags and prints what was written.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from federation.core.keys import DEFAULT_FEDERATION, validate_lab, validate_name

__all__ = [
    "CA_DAYS",
    "DEFAULT_DIR",
    "DEFAULT_HOSTS",
    "LEAF_DAYS",
    "CertError",
    "Issued",
    "agent_common_name",
    "agent_stem",
    "ca_common_name",
    "cfg_flags",
    "host_common_name",
    "host_stem",
    "init_ca",
    "issue_agent",
    "issue_host",
    "issue_lab",
    "tls_settings",
]

DEFAULT_DIR = Path("certs")
DEFAULT_HOSTS = ("localhost", "127.0.0.1", "::1")
CA_DAYS = 3650  # days a federation CA is valid
LEAF_DAYS = 825  # days a lab or agent certificate is valid (the CA/Browser Forum's old cap)
_BACKDATE = dt.timedelta(minutes=5)  # tolerate clocks a little behind the issuer's


class CertError(ValueError):
    """A certificate operation that cannot be done; the message says why and what to do."""


@dataclass(frozen=True)
class Issued:
    """Where a certificate and its key were written, and the certificate's Common Name."""

    cert: Path
    key: Path
    common_name: str


def ca_common_name(federation: str) -> str:
    """The federation CA's Common Name: ``"<federation> federation CA"``."""
    return f"{validate_name(federation, 'federation name')} federation CA"


def agent_common_name(lab: str, name: str) -> str:
    """An agent certificate's Common Name, ``"<lab>/<name>"``: what ACL subjects list."""
    return f"{validate_lab(lab)}/{validate_name(name, 'agent name')}"


def agent_stem(lab: str, name: str) -> str:
    """An agent's file name stem in the certificate folder, ``"<lab>.<name>"``."""
    return f"{validate_lab(lab)}.{validate_name(name, 'agent name')}"


def host_common_name(lab: str, host: str) -> str:
    """A hosted process's Common Name, ``"<lab>/hosts/<host>"`` (``fedlab host``): never
    an agent's, whose names hold no ``/``, so no agent's old certificate or password
    becomes a host's (nor the other way round) when a name moves between them."""
    return f"{validate_lab(lab)}/hosts/{validate_name(host, 'host name')}"


def host_stem(lab: str, host: str) -> str:
    """A hosted process's file name stem in the certificate folder, ``"<lab>.hosts.<host>"``."""
    return f"{validate_lab(lab)}.hosts.{validate_name(host, 'host name')}"


def tls_settings(
    directory: Path, stem: str | None = None, *, listen: bool = False
) -> dict[str, Any]:
    """Zenoh ``transport/link/tls`` settings (absolute paths) for one issued certificate.

    ``stem`` names the pair to show: a lab (``"kiruna"``) or an agent's file stem
    (``"kiruna.knatte"``, see :func:`agent_stem`); without one, only the CA, for a client
    that authenticates by password. ``listen`` adds the listening side (a router listens
    and dials with the same pair). Pass the result to :func:`cfg_flags` for ``--cfg``
    options, or insert it into a ``zenoh.Config``.
    """
    d = directory.resolve()
    settings: dict[str, Any] = {"transport/link/tls/root_ca_certificate": str(d / "ca.pem")}
    if stem is not None:
        sides = ("listen", "connect") if listen else ("connect",)
        for side in sides:
            settings[f"transport/link/tls/{side}_certificate"] = str(d / f"{stem}.pem")
            settings[f"transport/link/tls/{side}_private_key"] = str(d / f"{stem}.key")
        # A dialler shows its certificate only with mTLS enabled on its own side too.
        settings["transport/link/tls/enable_mtls"] = True
    return settings


def cfg_flags(settings: dict[str, Any]) -> list[str]:
    """``--cfg KEY:VALUE`` arguments (VALUE as JSON) for the given Zenoh settings."""
    flags: list[str] = []
    for key, value in settings.items():
        flags += ["--cfg", f"{key}:{json.dumps(value)}"]
    return flags


# -- issuing -----------------------------------------------------------------------
def init_ca(
    directory: Path,
    federation: str = DEFAULT_FEDERATION,
    *,
    force: bool = False,
    days: int = CA_DAYS,
    now: dt.datetime | None = None,
) -> Issued:
    """Create the federation CA (``ca.pem``, ``ca.key``) in ``directory``.

    Refuses to replace an existing CA unless ``force``: every certificate it signed
    would stop being trusted by routers that load the new one.
    """
    _check_days(days)
    cert_path, key_path = directory / "ca.pem", directory / "ca.key"
    if not force:
        for path in (cert_path, key_path):
            if path.exists():
                raise CertError(
                    f"{path} exists: replacing the CA invalidates every certificate it signed; "
                    "use --force to do it anyway"
                )
    common_name = ca_common_name(federation)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"fedlab {federation}"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )
    start = (now or dt.datetime.now(dt.UTC)) - _BACKDATE
    ski = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    cert = (
        _builder(name, name, key, start, start + dt.timedelta(days=days), ca=True)
        .add_extension(ski, critical=False)
        .sign(key, hashes.SHA256())
    )
    directory.mkdir(parents=True, exist_ok=True)
    _write_key(key_path, key)
    _write_cert(cert_path, cert)
    return Issued(cert_path, key_path, common_name)


def issue_lab(
    directory: Path,
    lab: str,
    hosts: Sequence[str] = DEFAULT_HOSTS,
    *,
    force: bool = False,
    days: int = LEAF_DAYS,
    now: dt.datetime | None = None,
) -> Issued:
    """Issue lab ``lab``'s router certificate (``<lab>.pem``, ``<lab>.key``), signed by the CA.

    CN is the lab name; ``hosts`` (DNS names or IP addresses) become its Subject
    Alternative Names, which a dialling router checks against the address it dials.
    It is valid both as a TLS server and as a TLS client: a router listens and dials
    with the same certificate.
    """
    validate_lab(lab)
    if not hosts:
        raise CertError("a lab certificate needs at least one host name (--host)")
    sans = [_san(h) for h in hosts]
    return _issue(directory, lab, lab, sans, server=True, force=force, days=days, now=now)


def issue_agent(
    directory: Path,
    lab: str,
    name: str,
    *,
    force: bool = False,
    days: int = LEAF_DAYS,
    now: dt.datetime | None = None,
) -> Issued:
    """Issue agent ``lab/name``'s client certificate (``<lab>.<name>.pem`` and ``.key``).

    CN is ``"<lab>/<name>"``; the certificate is valid as a TLS client only.
    """
    return _issue(
        directory,
        agent_stem(lab, name),
        agent_common_name(lab, name),
        [],
        server=False,
        force=force,
        days=days,
        now=now,
    )


def issue_host(
    directory: Path,
    lab: str,
    host: str,
    *,
    force: bool = False,
    days: int = LEAF_DAYS,
    now: dt.datetime | None = None,
) -> Issued:
    """Issue hosted process ``lab/hosts/host``'s client certificate
    (``<lab>.hosts.<host>.pem`` and ``.key``); valid as a TLS client only."""
    return _issue(
        directory,
        host_stem(lab, host),
        host_common_name(lab, host),
        [],
        server=False,
        force=force,
        days=days,
        now=now,
    )


def _issue(
    directory: Path,
    stem: str,
    common_name: str,
    sans: list[x509.GeneralName],
    *,
    server: bool,
    force: bool,
    days: int,
    now: dt.datetime | None,
) -> Issued:
    _check_days(days)
    ca_cert, ca_key = _load_ca(directory)
    cert_path, key_path = directory / f"{stem}.pem", directory / f"{stem}.key"
    if not force:
        for path in (cert_path, key_path):
            if path.exists():
                raise CertError(f"{path} exists; use --force to replace it")
    key = ec.generate_private_key(ec.SECP256R1())
    start = (now or dt.datetime.now(dt.UTC)) - _BACKDATE
    end = min(start + dt.timedelta(days=days), ca_cert.not_valid_after_utc)
    usages = [ExtendedKeyUsageOID.CLIENT_AUTH]
    if server:
        usages.insert(0, ExtendedKeyUsageOID.SERVER_AUTH)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])
    builder = (
        _builder(subject, ca_cert.subject, key, start, end, ca=False)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
            critical=False,
        )
    )
    if sans:
        builder = builder.add_extension(x509.SubjectAlternativeName(sans), critical=False)
    cert = builder.sign(ca_key, hashes.SHA256())
    _write_key(key_path, key)
    _write_cert(cert_path, cert)
    return Issued(cert_path, key_path, common_name)


def _builder(
    subject: x509.Name,
    issuer: x509.Name,
    key: ec.EllipticCurvePrivateKey,
    start: dt.datetime,
    end: dt.datetime,
    *,
    ca: bool,
) -> x509.CertificateBuilder:
    """What a CA and a leaf certificate share: names, key, validity, basic constraints
    and key usage. A CA (``ca``) signs certificates, and only leaves (path length 0); a
    leaf only signs its TLS handshakes."""
    usage = x509.KeyUsage(
        digital_signature=True,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=ca,
        crl_sign=ca,
        encipher_only=False,
        decipher_only=False,
    )
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(end)
        .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
        .add_extension(usage, critical=True)
    )


def _check_days(days: int) -> None:
    if days < 1:
        raise CertError(f"invalid validity {days} days: give at least 1")


def _san(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        pass
    if not host or any(c.isspace() or c in "/:*" for c in host):
        raise CertError(f"invalid host {host!r}: give a DNS name or an IP address")
    return x509.DNSName(host)


def _load_ca(directory: Path) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    cert_path, key_path = directory / "ca.pem", directory / "ca.key"
    if not cert_path.exists() or not key_path.exists():
        raise CertError(f"no federation CA in {directory}: run 'fedlab certs init' first")
    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except ValueError as error:
        raise CertError(f"{directory}: cannot read the CA: {error}") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey):
        raise CertError(f"{key_path}: expected an EC private key")
    return cert, key


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    _write_atomic(path, data, 0o600)


def _write_cert(path: Path, cert: x509.Certificate) -> None:
    _write_atomic(path, cert.public_bytes(serialization.Encoding.PEM), 0o644)


def _write_atomic(path: Path, data: bytes, mode: int) -> None:
    """Write via a temporary file created with ``mode`` (a key is never world-readable)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, mode)  # in case the umask trimmed it
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise

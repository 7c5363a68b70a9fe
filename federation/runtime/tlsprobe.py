"""A TLS handshake with a router, as a Zenoh client's config would make it, to say why
a session does not open (:mod:`federation.core.authfail` turns what it saw into words).

Zenoh reports a refused TLS link or login only as ``Unable to connect to any of
[...]``, and a client that retries for ever reports nothing. The probe dials the
endpoint with Python's TLS (OpenSSL), trusting the config's CA, showing its client
certificate, checking the router's name as Zenoh does (``verify_name_on_connect``),
then reads for :data:`SETTLE` s: a router that refuses the client's certificate sends
an alert then (TLS 1.3 finishes the client's side of the handshake first); one that
accepts it waits silently for the client's Zenoh handshake. The probe sends nothing
over the link: the router sees a TLS session that closes.
"""

from __future__ import annotations

import json
import socket
import ssl
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.x509.oid import NameOID

from federation.core.authfail import AuthFailure, ClientTls, TlsOutcome, explain

__all__ = ["SETTLE", "client_tls", "probe", "probe_endpoint"]

SETTLE = 0.5
"""s the probe waits, after its side of the handshake, for the router to refuse it."""

_TLS = "transport/link/tls/"


def _value(conf: Any, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except Exception:  # zenoh raises its own error for a key it does not know
        return None


def client_tls(conf: Any, source: str) -> ClientTls:
    """The TLS and login settings of a ``zenoh.Config``."""

    def text(key: str) -> str | None:
        value = _value(conf, key)
        return value if isinstance(value, str) and value else None

    cert = text(_TLS + "connect_certificate")
    return ClientTls(
        ca=text(_TLS + "root_ca_certificate"),
        cert=cert,
        key=text(_TLS + "connect_private_key"),
        mtls=_value(conf, _TLS + "enable_mtls") is True,
        verify_name=_value(conf, _TLS + "verify_name_on_connect") is not False,
        user=text("transport/auth/usrpwd/user"),
        source=source,
        cert_not_after=_not_after(cert),
    )


def _not_after(path: str | None) -> str | None:
    if path is None:
        return None
    try:
        cert = x509.load_pem_x509_certificate(Path(path).read_bytes())
    except (OSError, ValueError):
        return None
    return cert.not_valid_after_utc.isoformat(timespec="seconds")


def _context(client: ClientTls, verify: bool) -> ssl.SSLContext:
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    if verify:
        ctx.check_hostname = client.verify_name
        if client.ca is not None:
            ctx.load_verify_locations(client.ca)
        else:
            ctx.load_default_certs()
    else:
        ctx.check_hostname = False
        ctx.verify_mode = ssl.CERT_NONE
    if client.mtls and client.cert is not None and client.key is not None:
        ctx.load_cert_chain(client.cert, client.key)
    return ctx


def _router_certificate(
    host: str, port: int, client: ClientTls, timeout: float
) -> x509.Certificate:
    """The router's certificate, read without checking it."""
    ctx = _context(client, verify=False)
    with (
        socket.create_connection((host, port), timeout=timeout) as raw,
        ctx.wrap_socket(raw, server_hostname=host) as tls,
    ):
        der = tls.getpeercert(binary_form=True)
    if der is None:
        raise ssl.SSLError("the router showed no certificate")
    return x509.load_der_x509_certificate(der)


def _described(
    outcome: TlsOutcome, host: str, port: int, client: ClientTls, timeout: float
) -> TlsOutcome:
    """``outcome`` with the router certificate's names and issuer, when they can be read."""
    try:
        cert = _router_certificate(host, port, client, timeout)
    except (OSError, ValueError):
        return outcome
    try:
        sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        names = [str(n) for n in sans.get_values_for_type(x509.DNSName)]
        names += [str(a) for a in sans.get_values_for_type(x509.IPAddress)]
    except x509.ExtensionNotFound:
        names = []
    issuer = cert.issuer.get_attributes_for_oid(NameOID.COMMON_NAME)
    issued_by = str(issuer[0].value) if issuer else ""
    return TlsOutcome(outcome.stage, outcome.code, outcome.detail, tuple(names), issued_by)


def handshake(host: str, port: int, client: ClientTls, timeout: float = 2.0) -> TlsOutcome:
    """What a TLS handshake to ``host:port`` with ``client``'s settings sees. Raises
    OSError when TCP does not connect (that is :func:`~federation.runtime.session.diagnose`'s
    to say) and ssl/OSError when the client's own files cannot be loaded."""
    ctx = _context(client, verify=True)
    with socket.create_connection((host, port), timeout=timeout) as raw:
        try:
            with ctx.wrap_socket(raw, server_hostname=host) as tls:
                tls.settimeout(SETTLE)
                try:
                    tls.recv(1)
                except TimeoutError:
                    return TlsOutcome("accepted")
                return TlsOutcome("error", detail="the router closed the link after TLS")
        except ssl.SSLCertVerificationError as error:
            detail = str(error.verify_message or error.reason).rstrip(".")
            outcome = TlsOutcome("verify", str(error.reason), detail)
            return _described(outcome, host, port, client, timeout)
        except ssl.SSLError as error:
            if "ALERT" in str(error.reason):
                alert = str(error.reason).split("_ALERT_", 1)[-1].replace("_", " ").lower()
                return TlsOutcome("alert", str(error.reason), f"alert {alert!r}")
            return TlsOutcome("error", str(error.reason), str(error))
        except TimeoutError:
            return TlsOutcome("error", detail=f"no TLS answer within {timeout:g} s")
        except ConnectionResetError:
            return TlsOutcome("error", detail="the router reset the link during TLS")


def probe(
    host: str, port: int, endpoint: str, client: ClientTls, timeout: float = 2.0
) -> AuthFailure | None:
    """The authentication failure a TLS handshake with the router shows, or None (no TCP
    connection, or the handshake says nothing about one). A file of the client's that
    cannot be loaded is one too (kind ``client-files``)."""
    try:
        _context(client, verify=True)
    except (ssl.SSLError, OSError) as error:
        files = ", ".join(f for f in (client.ca, client.cert, client.key) if f)
        return AuthFailure(
            "client-files",
            f"cannot use this client's TLS files ({files}) from {client.source}: {error}",
        )
    try:
        outcome = handshake(host, port, client, timeout)
    except OSError:
        return None  # TCP did not connect: not an authentication failure
    return explain(endpoint, host, outcome, client)


def probe_endpoint(endpoint: str, client: ClientTls, timeout: float = 2.0) -> AuthFailure | None:
    """:func:`probe` for a ``tls/HOST:PORT[#...]`` endpoint; None for any other."""
    proto, _, address = endpoint.partition("/")
    host, sep, port = address.split("#", 1)[0].rpartition(":")
    if proto != "tls" or not sep or not port.isdigit():
        return None
    return probe(host.strip("[]"), int(port), endpoint, client, timeout)

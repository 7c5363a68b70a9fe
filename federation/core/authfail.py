"""Why a TLS router refuses a client, in words: what failed, where, and which file to check.

Zenoh says only ``Unable to connect to any of [tls/...]`` when a TLS or login failure
stops a session, and a client that retries for ever says nothing at all. fedlab probes
the endpoint with its own TLS handshake, using the client's CA, certificate and key
(:mod:`federation.runtime.tlsprobe`), and this module turns what the handshake saw into
a sentence. The rows, by what the probe saw:

===================================  =========================================  ==============
seen                                 meaning                                    kind
===================================  =========================================  ==============
verify: unable to get local issuer   the router's certificate is from another    router-ca
(or self-signed in chain)            CA than the one this client trusts
verify: certificate has expired      the router's certificate has expired         router-expired
verify: hostname / IP mismatch       the router's certificate does not name the   name
                                     host dialled
alert: unknown ca / decrypt error    the router does not trust this client's      client-ca
                                     certificate (signed by another CA)
alert: certificate expired           this client's certificate has expired        client-expired
alert: certificate required          the router wants a client certificate and    client-missing
                                     none was shown
alert: bad / unsupported certificate the router refused this client's             client-refused
                                     certificate
accepted, with a user and password   the router closed the session after TLS:     password
                                     the user or password is refused
accepted, without                    TLS is fine; the router closed the session   session
===================================  =========================================  ==============

An operator whose commands a router's access control drops is told by
:func:`refused_commands`: Zenoh drops a put that a router's ACL denies without a word
to the sender, so ctl sees it only as agents that never saw the command.

Pure: the probe's findings and the client's settings come in as data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = [
    "AuthFailure",
    "ClientTls",
    "TlsOutcome",
    "explain",
    "refused_commands",
]


@dataclass(frozen=True)
class ClientTls:
    """A client's TLS and login settings, as its Zenoh config names them."""

    ca: str | None = None
    """``root_ca_certificate``: the CA file the router's certificate must chain to."""
    cert: str | None = None
    """``connect_certificate``, shown to the router when ``mtls`` is set."""
    key: str | None = None
    mtls: bool = False
    """``enable_mtls``: without it a Zenoh client shows no certificate."""
    verify_name: bool = True
    """``verify_name_on_connect`` (Zenoh's default: on)."""
    user: str | None = None
    """``transport/auth/usrpwd/user`` when the client logs in with a password."""
    source: str = "the Zenoh config"
    """Where these settings come from (the config file), for messages."""
    cert_not_after: str | None = None
    """When the client's certificate expires (ISO date), if it could be read."""


@dataclass(frozen=True)
class TlsOutcome:
    """What a TLS handshake with the router saw.

    ``stage`` is ``verify`` (this side refused the router's certificate), ``alert`` (the
    router refused this side: ``code`` is OpenSSL's alert, e.g.
    ``TLSV1_ALERT_UNKNOWN_CA``), ``accepted`` (both sides agreed) or ``error`` (the
    handshake broke off otherwise: ``detail`` says how)."""

    stage: str
    code: str = ""
    detail: str = ""
    router_names: tuple[str, ...] = ()
    """The names (SANs) in the router's certificate, when it was seen."""
    router_issuer: str = ""
    """The Common Name of the router certificate's issuer, when it was seen."""


@dataclass(frozen=True)
class AuthFailure:
    """What failed (``kind``, see the module's table) and the sentence that says it."""

    kind: str
    message: str


_CLIENT_ALERTS = {
    "TLSV1_ALERT_UNKNOWN_CA": "client-ca",
    "TLSV1_ALERT_DECRYPT_ERROR": "client-ca",  # a CA of the same name: the signature fails
    "SSLV3_ALERT_CERTIFICATE_EXPIRED": "client-expired",
    "TLSV13_ALERT_CERTIFICATE_REQUIRED": "client-missing",
    "SSLV3_ALERT_BAD_CERTIFICATE": "client-refused",
    "SSLV3_ALERT_UNSUPPORTED_CERTIFICATE": "client-refused",
    "SSLV3_ALERT_CERTIFICATE_REVOKED": "client-refused",
    "TLSV1_ALERT_ACCESS_DENIED": "client-refused",
}


def _router_kind(detail: str) -> str:
    text = detail.lower()
    if "expired" in text:
        return "router-expired"
    if "mismatch" in text or "hostname" in text:
        return "name"
    return "router-ca"


def _names(outcome: TlsOutcome) -> str:
    return ", ".join(outcome.router_names) or "no name"


def explain(endpoint: str, host: str, outcome: TlsOutcome, client: ClientTls) -> AuthFailure | None:
    """The failure ``outcome`` shows for ``client`` dialling ``endpoint`` (whose host is
    ``host``), or None when the handshake says nothing about it (``error`` outcomes)."""
    ca = client.ca or "no CA file (root_ca_certificate)"
    cert = client.cert or "no certificate"
    if outcome.stage == "verify":
        kind = _router_kind(outcome.detail)
        if kind == "name":
            msg = (
                f"the router's certificate does not name {host}, the host dialled "
                f"({outcome.detail}; it names {_names(outcome)}): dial one of those names, "
                f"or issue the router a certificate for {host} (fedlab deploy generate, "
                f"fedlab certs issue --host {host})"
            )
        elif kind == "router-expired":
            msg = (
                f"the router's certificate has expired ({outcome.detail}): renew the "
                "router's certificate (fedlab certs issue --force) and restart the router"
            )
        else:
            issuer = f" (issued by {outcome.router_issuer!r})" if outcome.router_issuer else ""
            msg = (
                f"the router's certificate{issuer} is not signed by the CA this client "
                f"trusts, {ca} ({outcome.detail}): the router and this client belong to "
                f"different CAs; check root_ca_certificate in {client.source}"
            )
        return AuthFailure(kind, f"TLS to {endpoint} failed: {msg}")
    if outcome.stage == "alert":
        kind = _CLIENT_ALERTS.get(outcome.code, "client-refused")
        alert = outcome.detail or outcome.code
        if kind == "client-ca":
            msg = (
                f"the router does not trust this client's certificate {cert} ({alert}): "
                f"it was signed by another CA than the router's; use the certificate "
                f"issued with the router's CA (connect_certificate in {client.source})"
            )
        elif kind == "client-expired":
            until = f", valid until {client.cert_not_after}" if client.cert_not_after else ""
            msg = (
                f"the router refused this client's certificate {cert}: it has expired "
                f"({alert}{until}); issue a new one (fedlab deploy generate, fedlab certs "
                "issue-agent --force)"
            )
        elif kind == "client-missing":
            hint = "" if client.mtls or not client.cert else " (enable_mtls is off)"
            msg = (
                f"the router wants a client certificate and this client showed none{hint} "
                f"({alert}): set connect_certificate, connect_private_key and enable_mtls "
                f"in {client.source}"
            )
        else:
            msg = f"the router refused this client's certificate {cert} ({alert})"
        return AuthFailure(kind, f"TLS to {endpoint} failed: {msg}")
    if outcome.stage == "accepted":
        if client.user is not None:
            return AuthFailure(
                "password",
                f"TLS to {endpoint} is accepted but the router closes the session at login: "
                f"it refuses user {client.user!r} with the password in {client.source} (a "
                "wrong password, or a user not in the router's dictionary file; "
                "transport/auth/usrpwd)",
            )
        return AuthFailure(
            "session",
            f"TLS to {endpoint} is accepted but the router opens no Zenoh session (does it "
            "want a user and password, transport/auth/usrpwd?)",
        )
    return None


def refused_commands(
    key: str,
    identity: Mapping[str, str],
    source: str,
    reasons: Mapping[str, str],
    agents_seen: set[str] | frozenset[str],
) -> str | None:
    """Why no agent saw a command ctl put on ``key``, when that is the likely cause: its
    identity (``identity``: what its config ``source`` proves, e.g. ``{"certificate
    CN": "kiruna/knatte"}``) is not let put there by a router's access control. None
    when some agent saw the command (``reasons``: why each one did not confirm)."""
    if not reasons or not all(r.startswith("command not seen") for r in reasons.values()):
        return None
    if not identity:
        return (
            f"no agent saw the command on {key}: if the routers enforce access control, "
            f"this ctl proves no identity ({source} has no certificate or user) and may "
            "not command; use an operator's config (fedlab deploy generate writes "
            "<lab>/operators/<name>.json5)"
        )
    what, who = next(iter(identity.items()))
    fix = "use an operator's config (fedlab deploy generate writes <lab>/operators/<name>.json5)"
    if who in agents_seen:
        return (
            f"no agent saw the command on {key}: this ctl's identity is the {what} {who!r} "
            f"(from {source}), an agent's, and a router's access control lets an agent put "
            f"only under its own keys, operators alone on {key}: {fix}"
        )
    return (
        f"no agent saw the command on {key}: the router's access control may not let this "
        f"ctl's identity, the {what} {who!r} (from {source}), put there (only operators "
        f"may): {fix}"
    )

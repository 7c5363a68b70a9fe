"""An agent's identity is its name: the Common Name of the certificate its Zenoh config
shows, or the user name it logs in with, must be its fedlab address ``lab/name``.

The lab router's access control lets an identity write only under its own address
(:mod:`federation.deploy.generate`), so an agent started under another name would
publish into keys the router drops, silently. :func:`check_identity` refuses that
at start, before a session is opened, naming the file and both names.
"""

from __future__ import annotations

import base64
import binascii
from pathlib import Path

import zenoh
from cryptography import x509
from cryptography.x509.oid import NameOID

from federation.core.keys import AgentId
from federation.runtime.session import config_value
from schemas.base import ConfigError

__all__ = ["IdentityError", "certificate_cn", "check_identity", "identities"]

_CERT = "transport/link/tls/connect_certificate"
_USER = "transport/auth/usrpwd/user"


class IdentityError(ConfigError):
    """The identity in an agent's Zenoh config is not the agent's name."""


def certificate_cn(pem: bytes, source: str) -> str:
    """The Common Name of the first certificate in ``pem``; ``source`` names it in errors."""
    try:
        cert = x509.load_pem_x509_certificate(pem)
    except ValueError as error:
        raise IdentityError(f"{source}: not a PEM certificate: {error}") from None
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not names:
        raise IdentityError(f"{source}: the certificate has no Common Name")
    value = names[0].value
    return value if isinstance(value, str) else value.decode()


def identities(conf: zenoh.Config, source: str) -> dict[str, str]:
    """What a Zenoh client config proves about who it is: ``{"certificate CN": ...}``
    from its client certificate (file or base64), ``{"user name": ...}`` from its
    user/password; empty for a plain TCP client."""
    out: dict[str, str] = {}
    path = config_value(conf, _CERT)
    if isinstance(path, str) and path:
        try:
            pem = Path(path).read_bytes()
        except OSError as error:
            raise IdentityError(f"{source}: {_CERT} {path}: {error.strerror}") from None
        out["certificate CN"] = certificate_cn(pem, path)
    encoded = config_value(conf, _CERT + "_base64")
    if isinstance(encoded, str) and encoded:
        try:
            pem = base64.b64decode(encoded, validate=True)
        except (binascii.Error, ValueError):
            raise IdentityError(f"{source}: {_CERT}_base64 is not base64") from None
        out["certificate CN"] = certificate_cn(pem, f"{source}: {_CERT}_base64")
    user = config_value(conf, _USER)
    if isinstance(user, str) and user:
        out["user name"] = user
    return out


def check_identity(conf: zenoh.Config, agent: AgentId, source: str) -> None:
    """Refuse (IdentityError) if ``conf`` proves an identity other than ``agent``."""
    for what, value in identities(conf, source).items():
        if value != str(agent):
            raise IdentityError(
                f"{source}: the {what} is {value!r} but this agent is {agent}: the router "
                f"lets {value!r} write only under its own keys. Run it as --lab "
                f"{value.partition('/')[0]} --name {value.partition('/')[2]}, or give it its "
                f"own certificate or user (fedlab deploy generate, fedlab certs issue-agent)"
            )

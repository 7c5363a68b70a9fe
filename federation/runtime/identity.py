"""An agent's identity is its name: the Common Name of the certificate its Zenoh config
shows, or the user name it logs in with, must be its fedlab address ``lab/name``.

The lab router's access control lets an identity write only under its own address
(:mod:`federation.deploy.generate`), so an agent started under another name would
publish into keys the router drops, silently. :func:`check_identity` refuses that
at start, before a session is opened, naming the file and both names.

A hosted process (``fedlab host``, a lab's ``hosted`` in the federation file) has an
identity of its own, ``lab/hosts/<host>``, which writes for the agents it runs; its
generated Zenoh config lists them (``metadata.fedlab_hosted``), and
:func:`check_hosted_identity` refuses an agent not listed, for the same reason.
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

__all__ = [
    "HOSTED_FIELD",
    "IdentityError",
    "certificate_cn",
    "check_hosted_identity",
    "check_identity",
    "identities",
]

_CERT = "transport/link/tls/connect_certificate"
_USER = "transport/auth/usrpwd/user"
HOSTED_FIELD = "fedlab_hosted"
"""The field of a hosted process's Zenoh config ``metadata``: the agents (``lab/name``)
its identity may speak for."""


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


def check_identity(conf: zenoh.Config, agent: AgentId | str, source: str) -> None:
    """Refuse (IdentityError) if ``conf`` proves an identity other than ``agent``
    (``lab/name``)."""
    for what, value in identities(conf, source).items():
        if value == str(agent):
            continue
        if _hosted(conf) is not None:
            raise IdentityError(
                f"{source}: the {what} is {value!r}, a hosted process's (it lists the agents "
                f"it runs in metadata.{HOSTED_FIELD}): run it with fedlab host, not as agent "
                f"{agent}"
            )
        raise IdentityError(
            f"{source}: the {what} is {value!r} but this agent is {agent}: the router "
            f"lets {value!r} write only under its own keys. Run it as --lab "
            f"{value.partition('/')[0]} --name {value.partition('/')[2]}, or give it its "
            f"own certificate or user (fedlab deploy generate, fedlab certs issue-agent)"
        )


def check_hosted_identity(conf: zenoh.Config, agents: list[AgentId], source: str) -> None:
    """Refuse (IdentityError) an identity in ``conf`` that may not speak for every one of
    ``agents``: one agent's own, or a hosted process's whose config lists them all
    (``metadata.fedlab_hosted``). Nothing to prove (a plain link): nothing refused."""
    proved = identities(conf, source)
    if not proved:
        return
    _one_identity(proved, source)
    what, value = next(iter(proved.items()))
    listed = _hosted(conf)
    if listed is None:
        if len(agents) == 1:
            check_identity(conf, agents[0], source)
            return
        raise IdentityError(
            f"{source}: the {what} is {value!r}, which lists no hosted agents "
            f"(metadata.{HOSTED_FIELD}): the lab router lets it write only under its own "
            f"keys, so {len(agents)} agents on this one session would have what they send "
            f"dropped. List them under labs.<lab>.hosted in the federation file and use the "
            f"generated hosts/<host>.json5 (fedlab deploy generate), or run each as its own "
            f"fedlab agent"
        )
    if not (isinstance(listed, list) and all(isinstance(a, str) for a in listed)):
        raise IdentityError(f"{source}: metadata.{HOSTED_FIELD}: a list of lab/name expected")
    missing = [str(a) for a in agents if str(a) not in listed]
    if missing:
        raise IdentityError(
            f"{source}: {', '.join(missing)} not among the agents the {what} {value!r} may "
            f"speak for ({', '.join(listed) or 'none'}): the lab router would drop what "
            f"{'it sends' if len(missing) == 1 else 'they send'}. Add "
            f"{'it' if len(missing) == 1 else 'them'} to this host in the federation file "
            f"and generate again"
        )


def _one_identity(proved: dict[str, str], source: str) -> None:
    """Refuse a config that proves two identities (a certificate CN and a user name that
    differ): the router would judge it by either, so which agents it speaks for is not
    one answer."""
    if len(set(proved.values())) > 1:
        said = " and ".join(f"the {what} is {value!r}" for what, value in proved.items())
        raise IdentityError(
            f"{source}: {said}: one session proves one identity; give both the same "
            f"name, or drop one"
        )


def _hosted(conf: zenoh.Config) -> object:
    """What a Zenoh config lists at ``metadata.fedlab_hosted`` (None without it)."""
    metadata = config_value(conf, "metadata")  # Zenoh reads no key inside it
    return metadata.get(HOSTED_FIELD) if isinstance(metadata, dict) else None

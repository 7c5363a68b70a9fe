"""How one lab's router reaches another's: QUIC with mixed reliability, or TLS over TCP.

Over TLS/TCP every message behind a lost segment waits for its retransmission (a round
trip at least, often the 0.2 s timeout): at 5 % loss and 40 ms one way the pose's p99
was 200 to 214 ms and the follower was held 1 to 5 times a minute. Zenoh 1.10's QUIC
link with ``mixed_rel=1`` carries reliable messages (declarations, sync, status,
control) on one encrypted stream and best-effort ones (pose) as datagrams of the same
connection, so a pose never waits behind a lost packet: p99 88 to 112 ms and no stale
hold in five 60 s runs of the bench's routers, 105 to 133 ms and none in three runs of
the generated deployment itself on busier cores (docs/deploy.md). QUIC
reads the same ``transport/link/tls`` settings, so the router's certificate, its name
check and the access control by certificate name hold on it unchanged.

A lab with certificate auth is dialled over QUIC (on UDP, the listener's port number)
when the federation's ``lab_link`` is ``quic``, its default; a password lab's listeners
take no client certificate, so another lab's router could not be known on them by its
certificate: it is dialled over TLS. Agents and operators always reach their own
router over TLS.
"""

from __future__ import annotations

from schemas.federation import FederationFile

__all__ = ["MIXED", "dial", "listen_quic", "protocols", "quic_endpoint"]

MIXED = "mixed_rel=1"
"""The endpoint metadata that puts best-effort messages on QUIC datagrams."""


def quic_endpoint(tls: str) -> str:
    """``tls/HOST:PORT[#config]`` as ``quic/HOST:PORT?mixed_rel=1[#config]``, with
    ``localhost`` as ``127.0.0.1``: a router dialling ``quic/localhost:PORT`` never
    linked to a listener on ``quic/127.0.0.1:PORT`` on this project's hosts, where
    ``tls/localhost:PORT`` does (the certificates ``--local`` writes name both)."""
    scheme, sep, rest = tls.partition("/")
    if scheme != "tls" or not sep:
        raise ValueError(f"expected a tls/ endpoint, not {tls!r}")
    address, hash_, config = rest.partition("#")
    if address.startswith("localhost:"):
        address = "127.0.0.1:" + address.removeprefix("localhost:")
    return f"quic/{address}?{MIXED}{hash_}{config}"


def _over_quic(fed: FederationFile, lab: str) -> bool:
    """Whether routers dial lab ``lab`` over QUIC."""
    return fed.lab_link == "quic" and fed.labs[lab].auth == "certificate"


def listen_quic(fed: FederationFile, lab: str) -> list[str]:
    """The QUIC listeners lab ``lab``'s router adds beside its TLS ones: one per TLS
    listener, if another lab dials it over QUIC."""
    dialled = any(lab in entry.dial for entry in fed.labs.values())
    if not (dialled and _over_quic(fed, lab)):
        return []
    return [quic_endpoint(e) for e in fed.labs[lab].listen]


def dial(fed: FederationFile, lab: str) -> list[str]:
    """The endpoints lab ``lab``'s router dials: each lab in its ``dial``."""
    out = []
    for other in fed.labs[lab].dial:
        endpoint = fed.labs[other].endpoint
        assert endpoint is not None  # checked when the federation file loads
        out.append(quic_endpoint(endpoint) if _over_quic(fed, other) else endpoint)
    return out


def protocols(fed: FederationFile, lab: str) -> list[str]:
    """The link protocols lab ``lab``'s router allows: TLS, and QUIC where it listens or
    dials over it."""
    uses = bool(listen_quic(fed, lab)) or any(_over_quic(fed, o) for o in fed.labs[lab].dial)
    return ["tls", "quic"] if uses else ["tls"]

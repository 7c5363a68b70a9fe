"""A federation moved onto one host, to rehearse it (``fedlab deploy generate --local``).

Every lab keeps its agents, operators, dials and authentication; what changes is where
its router is found. A lab whose endpoints all name this host (``127.0.0.1``, ``::1``,
``localhost``) keeps them; any other lab listens on ``tls/127.0.0.1:PORT`` and is
dialled at ``tls/localhost:PORT``, its certificate naming ``localhost`` and
``127.0.0.1``, so that routers and agents connect over TLS with no edit. Each lab gets
a port of its own: ``port`` + its place in the file when a first port is given, else
the port it listens on in the file, or the next one up that no earlier lab has::

    kiruna  listen tls/[::]:7447        ->  tls/127.0.0.1:7447, dialled tls/localhost:7447
    rome    listen tls/192.0.2.2:7447   ->  tls/127.0.0.1:7448, dialled tls/localhost:7448
"""

from __future__ import annotations

import ipaddress

from schemas.base import ConfigError
from schemas.federation import FederationFile, LabEntry, endpoint_host

__all__ = ["LOOPBACK_HOSTS", "localize"]

LOOPBACK_HOSTS = ["localhost", "127.0.0.1"]
"""The names a moved lab's certificate carries: what its agents and neighbours dial
(``localhost``) and what it listens on (``127.0.0.1``)."""
_MAX_PORT = 65535


def _on_this_host(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _port(endpoint: str) -> int:
    return int(endpoint.partition("/")[2].split("#", 1)[0].rpartition(":")[2])


def _options(endpoint: str) -> str:
    """An endpoint's ``#...`` options (e.g. ``#enable_mtls=false``), or ''."""
    _, sep, options = endpoint.partition("#")
    return sep + options


def _local(entry: LabEntry) -> bool:
    dialled = [entry.endpoint, entry.agent_endpoint, *entry.listen]
    return all(_on_this_host(endpoint_host(e)) for e in dialled if e is not None)


def _moved(entry: LabEntry, port: int) -> LabEntry:
    listen = [f"tls/127.0.0.1:{port}{_options(entry.listen[0])}"]
    here = f"tls/localhost:{port}"
    return entry.model_copy(
        update={
            "listen": listen,
            "endpoint": here if entry.endpoint is not None else None,
            "agent_endpoint": here if entry.agent_endpoint is not None else None,
            "hosts": list(LOOPBACK_HOSTS),
        }
    )


def localize(fed: FederationFile, port: int | None = None) -> FederationFile:
    """``fed`` on this host (see the module docstring). ``port``: the first lab's port,
    the next lab's one up, and so on (every lab moved, a local one too); a ConfigError
    if they run past 65535."""
    if port is not None and port + len(fed.labs) - 1 > _MAX_PORT:
        raise ConfigError(
            f"--port {port}: {len(fed.labs)} labs need ports {port} to "
            f"{port + len(fed.labs) - 1}, past {_MAX_PORT}"
        )
    kept = {} if port is not None else {lab: e for lab, e in fed.labs.items() if _local(e)}
    taken = {_port(listen) for entry in kept.values() for listen in entry.listen}
    labs: dict[str, LabEntry] = {}
    for i, (lab, entry) in enumerate(fed.labs.items()):
        if lab in kept:
            labs[lab] = entry
            continue
        chosen = port + i if port is not None else _port(entry.listen[0])
        while chosen in taken:  # bounded: at most one step per lab
            chosen += 1
        if chosen > _MAX_PORT:
            raise ConfigError(f"labs.{lab}: no port left above {_port(entry.listen[0])}")
        taken.add(chosen)
        labs[lab] = _moved(entry, chosen)
    return fed.model_copy(update={"labs": labs})

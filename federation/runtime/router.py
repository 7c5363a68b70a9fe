"""A lab router, run from Python (zenohd is not installable here).

One lab's router listens; the other labs' routers dial it (``connect``), so a
dialling lab opens no inbound port: its one outbound link carries traffic both
ways. Routers retry a configured endpoint forever and re-form the link after it
drops, so either side can restart.

Router files under deploy/routers/ are plain zenohd json5 configs; the lab's
name is kept in ``metadata.lab`` so the same file works with the official binary.
"""

from __future__ import annotations

import ipaddress
import logging
import threading
from typing import Any

import zenoh

from federation.runtime.session import ZenohConfigError, build_config, config_value
from federation.runtime.zenoh_text import without_source_location
from schemas.config import ConfigError, RouterConfig, ZenohOptions, validate
from schemas.federation import endpoint_host

__all__ = ["load_router_config", "refuse_reachable_agent", "run_router"]

log = logging.getLogger("fedlab.router")

_ROUTER_DEFAULTS: dict[str, Any] = {
    # A router keeps dialling the other lab forever and never gives up at start.
    "connect/timeout_ms": -1,
    "connect/exit_on_failure": False,
}


def load_router_config(
    options: ZenohOptions, lab: str | None, open_: bool = False
) -> tuple[RouterConfig, zenoh.Config]:
    """Validated router settings and the Zenoh config that realises them. A listener
    reachable beyond this host without access control (enabled, default deny) is
    refused unless ``open_``: whoever reaches its port could publish control or another
    agent's pose, and move a platform."""
    source = str(options.config) if options.config else "command line"
    conf = build_config(options, default_mode="router", extra=_ROUTER_DEFAULTS)
    mode = config_value(conf, "mode")
    if mode not in (None, "router"):
        raise ConfigError(
            f"{source}: field 'mode': a lab router must have mode 'router', not {mode!r}"
        )
    metadata = config_value(conf, "metadata") or {}
    lab = lab or (metadata.get("lab") if isinstance(metadata, dict) else None)
    if lab is None:
        raise ConfigError(
            f"{source}: field 'metadata.lab': missing; give --lab LAB or set it in the file"
        )
    data = {
        "lab": lab,
        "listen": _endpoints(config_value(conf, "listen/endpoints")),
        "connect": _endpoints(config_value(conf, "connect/endpoints")),
    }
    settings = validate(RouterConfig, data, source)
    if not settings.listen and not settings.connect:
        raise ConfigError(
            f"{source}: field 'listen': a router needs at least one listen or connect endpoint"
        )
    if not open_:
        _refuse_open_listeners(conf, settings.listen, source)
        _refuse_plain_dial(conf, settings.connect, source)
    # Keep the lab name in the config so it shows in Zenoh's admin space.
    conf.insert_json5("metadata", f'{{"lab": "{settings.lab}"}}')
    return settings, conf


def _guarded(conf: zenoh.Config) -> bool:
    """Whether access control is on and denies what no rule allows."""
    acl = config_value(conf, "access_control") or {}
    return (
        isinstance(acl, dict) and acl.get("enabled") is True
        and acl.get("default_permission") == "deny"
    )  # fmt: skip


def _refuse_open_listeners(conf: zenoh.Config, listen: list[str], source: str) -> None:
    if _guarded(conf):
        return
    for endpoint in listen:
        if not _local_only(endpoint):
            raise ConfigError(
                f"{source}: field 'listen': {endpoint} is reachable beyond this host and no "
                "access control is on (access_control.enabled, default_permission deny): "
                "whoever reaches the port could publish control or an agent's pose. Use the "
                "configs of fedlab deploy generate (TLS, access control), listen on a "
                "loopback address, or pass --open on a network you trust (a testbed)"
            )


def _refuse_plain_dial(conf: zenoh.Config, connect: list[str], source: str) -> None:
    """Refuse a plain (not TLS, not QUIC) link to another host's router without access
    control: nothing proves who answers, and what it sends (control, any agent's pose)
    would be carried into this lab. Loopback, a testbed (``--open``), or TLS."""
    if _guarded(conf):  # on, and denying what no rule allows (an allow-all is no guard)
        return
    for endpoint in connect:
        proto = endpoint.partition("/")[0]
        if proto in ("tls", "quic") or _local_only(endpoint):
            continue
        raise ConfigError(
            f"{source}: field 'connect': {endpoint} is a plain link to another host and no "
            "access control is on (access_control.enabled, default_permission deny): "
            "whoever answers there could send control or any agent's pose into this lab. "
            "Use the configs of fedlab deploy generate (TLS, access control), or pass "
            "--open on a network you trust (a testbed)"
        )


def refuse_reachable_agent(conf: zenoh.Config, source: str) -> None:
    """Refuse (ConfigError) an agent's session that others could reach without its lab
    router: a peer or router session listening beyond this host (a peer with no listen
    endpoint listens on every interface). Whoever reached it could publish control or
    the followed agent's pose straight into the agent; the router's access control is
    what keeps them out, so an agent joins as its client."""
    mode = config_value(conf, "mode")
    if mode in (None, "client"):
        return
    listen = config_value(conf, "listen/endpoints")
    if isinstance(listen, dict):
        listen = listen.get(mode, [])
    endpoints = list(listen or [])
    reachable = [e for e in endpoints if not _local_only(e)]
    if not endpoints:
        reachable = ["every interface (its default)"]
    if reachable:
        raise ConfigError(
            f"{source}: field 'mode': an agent in {mode} mode listens on "
            f"{', '.join(reachable)}, reachable without its lab router's access control: "
            "run it as a client of the router (mode client), or listen on loopback only"
        )


def _local_only(endpoint: str) -> bool:
    """Whether an endpoint listens on this host only (a loopback address, a Unix socket)."""
    proto = endpoint.partition("/")[0]
    if proto.startswith("unixsock"):
        return True
    host = endpoint_host(endpoint)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name, or the wildcard's empty host: assume the world


def _endpoints(value: Any) -> list[str]:
    # zenohd allows per-mode endpoint maps ({router: [...], peer: [...]}).
    if isinstance(value, dict):
        value = value.get("router", [])
    return list(value or [])


def run_router(settings: RouterConfig, conf: zenoh.Config, stop: threading.Event) -> None:
    """Run until ``stop`` is set."""
    try:
        session = zenoh.open(conf)
    except Exception as error:
        why = without_source_location(str(error))
        raise ZenohConfigError(f"router {settings.lab}: cannot start: {why}") from None
    with session:
        log.info(
            "router %s up (zid %s), listening on %s, dialling %s",
            settings.lab,
            session.zid(),
            ", ".join(settings.listen) or "nothing",
            ", ".join(settings.connect) or "nothing",
        )
        stop.wait()
        log.info("router %s stopping", settings.lab)

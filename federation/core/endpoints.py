"""Zenoh endpoints checked as text, before any session: ``PROTOCOL/ADDRESS``, and for
the protocols that carry a port (tcp, udp, tls, quic, ws) ``HOST:PORT`` with IPv6 in
brackets. Zenoh's own ``?metadata`` and ``#config`` parts are left to Zenoh.

A locator without its port is otherwise passed to Zenoh, which dials nothing and
reports, after the whole timeout, that no router answered.
"""

from __future__ import annotations

__all__ = ["PORTED", "endpoint_problem"]

PORTED = frozenset({"tcp", "udp", "tls", "quic", "ws"})
"""The protocols whose address is ``HOST:PORT``."""


def endpoint_problem(endpoint: str) -> str | None:
    """What is wrong with ``endpoint`` (one clause, naming what to write), or None."""
    proto, sep, rest = endpoint.partition("/")
    if not sep or not proto or not rest:
        return "expected PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447"
    if proto not in PORTED:
        return None  # unixsock-stream/PATH, serial/DEVICE, ...: Zenoh checks them
    address = rest.split("#", 1)[0].split("?", 1)[0]
    if address.startswith("["):
        inside, bracket, after = address[1:].partition("]")
        if not bracket or not inside:
            return f"{address!r} opens a bracket it does not close, e.g. {proto}/[::1]:7447"
        if after and not after.startswith(":"):
            return f"expected :PORT after [{inside}], e.g. {proto}/[{inside}]:7447"
        host, port = f"[{inside}]", after[1:]
    else:
        host, _, port = address.partition(":")
        if ":" in port:  # a second colon: an IPv6 address
            return f"an IPv6 address goes in brackets, e.g. {proto}/[::1]:7447"
        if not host:
            return f"no host before :{port}, e.g. {proto}/127.0.0.1:{port or 7447}"
    if not port:
        return f"no port: write {proto}/{host}:PORT, e.g. {proto}/{host}:7447"
    if not port.isdigit() or int(port) > 65535:
        return f"the port is a number from 0 to 65535, not {port!r}"
    return None

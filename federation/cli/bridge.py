"""``fedlab bridge udp``: join an unchanged legacy agent that speaks the paper's UDP
packets to the federation (the library: :mod:`federation.bridge.udp`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_zenoh_flags,
    open_interruptible,
    stop_on_signals,
    zenoh_options,
)
from federation.core.estimators import ESTIMATORS
from schemas.bridge import UdpBridgeConfig
from schemas.config import validate

__all__ = ["add", "run"]

_EXAMPLE = (
    "Example:\n"
    "  fedlab bridge udp --as rome/pinocchio --listen 0.0.0.0:9000 --peer 192.0.2.7:9001 \\\n"
    "      --follow kiruna/knatte -e tcp/127.0.0.1:7448"
)

# UdpBridgeConfig field -> the flag's destination, where they differ.
_DESTS = {"agent": "as_agent", "listen": "udp_listen"}


def _default(field: str) -> Any:
    """The default of a UdpBridgeConfig field: kept there, shown in --help."""
    return UdpBridgeConfig.model_fields[field].default


def _seconds(p: argparse.ArgumentParser, flag: str, help_text: str) -> None:
    """A duration flag whose default is its UdpBridgeConfig field's."""
    field = flag.removeprefix("--").replace("-", "_")
    p.add_argument(flag, type=float, default=_default(field), metavar="S", help=help_text)


def add(sub: Subparsers) -> None:
    """Add ``bridge`` and its one kind, ``bridge udp``."""
    bridge = sub.add_parser(
        "bridge",
        help="join a legacy agent to the federation (the paper's UDP packets)",
        formatter_class=Formatter,
        description="Bridges that let an unchanged legacy agent join the federation.",
        epilog=_EXAMPLE,
    )
    kinds = bridge.add_subparsers(dest="bridge", required=True, metavar="KIND")
    p = kinds.add_parser(
        "udp",
        help="a legacy agent speaking the paper's UDP packets (8-byte request, 64-byte reply)",
        formatter_class=Formatter,
        description=(
            "Join an unchanged legacy agent that speaks the paper's UDP packets to the\n"
            "federation as LAB/NAME. Its 8-byte requests to --listen get 64-byte replies\n"
            "with t2 on the reference (leader's) clock and the followed agent's pose. The\n"
            "bridge's own requests to --peer (every --sync-period) give the legacy agent's\n"
            "clock and pose, served to the federation as LAB/NAME's sync, pose and status.\n"
            "The first request opens the firewall flow; the requests keep it open.\n\n"
            "Zenoh's own listen endpoint is -l here; --listen is the UDP address."
        ),
        epilog=_EXAMPLE,
        conflict_handler="resolve",  # --listen is the UDP address; Zenoh keeps -l
    )
    add_zenoh_flags(p)
    p.add_argument(
        "--as", dest="as_agent", required=True, metavar="LAB/NAME",
        help="the legacy agent's name in the federation",
    )  # fmt: skip
    p.add_argument(
        "--listen", dest="udp_listen", required=True, metavar="HOST:PORT",
        help="UDP address the legacy agent sends its requests to (and that sends ours)",
    )  # fmt: skip
    p.add_argument(
        "--peer", required=True, metavar="HOST:PORT",
        help="the legacy agent's UDP address: where the bridge's requests go",
    )  # fmt: skip
    p.add_argument(
        "--follow", metavar="LAB/NAME",
        help="agent whose clock and pose the legacy agent receives; "
        "none: the federation's leader, found by its status",
    )  # fmt: skip
    p.add_argument(
        "--role", choices=["follower", "leader"], default=_default("role"),
        help="leader: the legacy agent's clock is the reference time",
    )  # fmt: skip
    p.add_argument("--federation", default=_default("federation"), help="federation name")
    _seconds(p, "--sync-period", "seconds between requests")
    _seconds(p, "--sync-timeout", "reply timeout")
    _seconds(p, "--sync-window", "offset averaging window")
    p.add_argument(
        "--estimator", choices=list(ESTIMATORS), default=_default("estimator"),
        help="offset estimator for both links",
    )  # fmt: skip
    _seconds(
        p, "--legacy-timeout", "seconds without a reply before the legacy agent counts as gone"
    )
    _seconds(p, "--status-period", "seconds between status")
    p.add_argument("--status-json", type=Path, metavar="FILE", help="append status lines here")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    p.set_defaults(func=run)


def bridge_config(args: argparse.Namespace) -> UdpBridgeConfig:
    """The bridge's settings from the flags; ConfigError naming the field if one is bad."""
    data = {name: getattr(args, _DESTS.get(name, name)) for name in UdpBridgeConfig.model_fields}
    return validate(UdpBridgeConfig, data, "command line")


def run(args: argparse.Namespace) -> int:
    import zenoh

    from federation.bridge.udp import bind_udp, run_bridge
    from federation.runtime.session import build_config

    config = bridge_config(args)
    conf = build_config(zenoh_options(args), default_mode="client")
    sock = bind_udp(config.listen_address)  # a port in use fails now, not after the router
    stop = stop_on_signals()
    try:
        session = open_interruptible(zenoh.open, conf, stop)
    except BaseException:
        sock.close()
        raise
    if session is None:
        sock.close()
        return 0
    with session:
        run_bridge(config, session, sock, stop)
    return 0

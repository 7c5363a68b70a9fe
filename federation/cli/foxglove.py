"""``fedlab foxglove``: a live view of a federation in Foxglove (the library:
:mod:`federation.runtime.foxglove`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_federation_flag,
    add_timeout_flag,
    add_zenoh_flags,
    integer_in,
    open_session,
    positive,
    stop_on_signals,
)

__all__ = ["add", "run"]


_port = integer_in(0, 65535, "a port number")


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "foxglove",
        help="live view of every agent in Foxglove (WebSocket server)",
        formatter_class=Formatter,
        description=(
            "Serve a live view of a federation to Foxglove (foxglove.websocket.v1): every\n"
            "agent's pose as transforms fedlab_common -> LAB/NAME on /tf, the platforms'\n"
            "footprints and the labs' work areas on /scene, offset, delay and error bound\n"
            "per peer on /fedlab/peers and /fedlab/sync/..., run mode and run time on\n"
            "/fedlab/run. In Foxglove: Open connection, Foxglove WebSocket, ws://HOST:PORT;\n"
            "then import a layout: --layout FILE writes one for the agents seen (plots per\n"
            "peer; rewritten as agents appear), deploy/foxglove/fedlab.json has the panels\n"
            "of any federation. Subscribes like fedlab monitor."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab foxglove -e tcp/127.0.0.1:7447\n"
            "  fedlab foxglove --layout fedlab-layout.json -e tcp/127.0.0.1:7447\n"
            "  fedlab foxglove --host 0.0.0.0 --port 8766 --federation demo -e tcp/127.0.0.1:7447"
        ),
    )
    add_federation_flag(p)
    p.add_argument("--host", default="127.0.0.1", help="address the WebSocket server binds")
    p.add_argument("--port", type=_port, default=8765, help="its port (0: any free one)")
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--layout",
        type=Path,
        metavar="FILE",
        help="write a Foxglove layout of the agents seen to FILE (rewritten as they appear)",
    )
    add_zenoh_flags(p)
    add_timeout_flag(p, service=True)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from federation.runtime.foxglove import serve, write_layout

    if args.layout is not None:
        try:  # before waiting for a router: a bad path fails at once
            write_layout(args.layout, ())
        except OSError as error:
            print(f"fedlab foxglove: error: cannot write the layout: {error}", file=sys.stderr)
            return 1
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    with session:
        try:
            serve(session, stop, args.federation, args.host, args.port, args.duration, args.layout)
        except OSError as error:
            print(f"fedlab foxglove: error: cannot write the layout: {error}", file=sys.stderr)
            return 1
        except RuntimeError as error:  # the SDK's server could not bind
            print(
                f"fedlab foxglove: error: cannot serve on {args.host}:{args.port}: {error}",
                file=sys.stderr,
            )
            return 1
    return 0

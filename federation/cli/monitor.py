"""``fedlab monitor``: a live terminal view of every agent in a federation.

Parses, watches through :class:`federation.runtime.monitor.Watch` and shows the
table live, or one snapshot (``--once``, as a table or ``--json``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_federation_flag,
    add_timeout_flag,
    add_zenoh_flags,
    nonnegative,
    open_session,
    stop_on_signals,
)

__all__ = ["add", "run"]

_PIPE_WIDTH = 140  # columns of the table written to a file or pipe


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "monitor",
        help="live view of every agent in a federation",
        formatter_class=Formatter,
        description=(
            "Show every agent of a federation, refreshed once a second: role, mode, platform,\n"
            "clock offset to its reference and delay, pose age, sync samples, rejected inputs,\n"
            "control loop lateness and the age of its last status. Stale rows are dimmed;\n"
            "agents whose liveliness token is gone are shown as 'left'."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab monitor -e tcp/127.0.0.1:7447\n"
            "  fedlab monitor --federation demo -e tcp/kiruna.example.org:7447\n"
            "  fedlab monitor -e tcp/127.0.0.1:7447 --once --wait 3 --json"
        ),
    )
    add_federation_flag(p)
    p.add_argument(
        "--duration", type=nonnegative, default=None, metavar="S", help="stop after S seconds"
    )
    p.add_argument(
        "--once", action="store_true", help="print one snapshot after --wait seconds and exit"
    )
    p.add_argument(
        "--wait", type=nonnegative, default=3.0, metavar="S", help="with --once: seconds to listen"
    )
    p.add_argument("--json", action="store_true", help="with --once: print the rows as JSON")
    add_timeout_flag(p)
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from federation.runtime.monitor import Watch, live

    if args.json and not args.once:
        print("fedlab monitor: error: --json needs --once", file=sys.stderr)
        return 2
    console = Console()
    if not console.is_terminal and "COLUMNS" not in os.environ:
        console = Console(width=_PIPE_WIDTH)  # a file or pipe: the full table, not 80 columns
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    with session, Watch(session, args.federation) as watch:
        if not args.once:
            live(watch, console, stop, args.duration)
            return 0
        stop.wait(args.wait)
        snapshot = watch.snapshot()
    if args.json:
        # print, not console.print: scripts want the bare JSON, unwrapped.
        print(json.dumps(snapshot.as_json(), indent=2), flush=True)
    else:
        console.print(snapshot.table(console))
    return 0

"""``fedlab ctl start|freeze|resume|abort``: execution control over the federation.

Parses, calls :func:`federation.runtime.control.issue` and prints who confirmed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_zenoh_flags,
    agent_id,
    federation_name,
    nonnegative,
    open_session,
    stop_on_signals,
)
from federation.core import keys
from federation.runtime import control

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "ctl",
        help="start, freeze, resume or abort a run across the federation",
        formatter_class=Formatter,
        description=(
            "start syncs with the reference agent (the experiment's leader) exactly as agents\n"
            "do, then announces a start at a reference time --in seconds ahead; every agent\n"
            "begins when its own synchronized clock reaches that instant. The other commands\n"
            "act on receipt. Each command is published a few times with the same sequence\n"
            "number (agents ignore repeats) and ctl waits, bounded, until every expected agent\n"
            "reports the new mode. Exit code 1 if one did not."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab ctl start --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl abort -e tcp/127.0.0.1:7447"
        ),
    )
    p.add_argument(
        "action",
        choices=control.ACTIONS,
        help="start at a common instant, or freeze, resume or abort on receipt",
    )
    p.add_argument("--experiment", type=Path, metavar="FILE", help="experiment file (TOML)")
    p.add_argument(
        "--federation",
        type=federation_name,
        default=keys.DEFAULT_FEDERATION,
        help="federation name (an experiment's own wins)",
    )
    p.add_argument(
        "--reference", type=agent_id, metavar="LAB/NAME", help="agent whose clock is reference time"
    )
    p.add_argument(
        "--in",
        dest="start_in",
        type=nonnegative,
        metavar="S",
        help="start this many seconds ahead "
        f"(default: the experiment's start_delay, else {control.DEFAULT_START_IN:g})",
    )
    p.add_argument(
        "--wait", type=nonnegative, default=5.0, metavar="S", help="confirmation timeout"
    )
    p.add_argument(
        "--discover", type=nonnegative, default=1.5, metavar="S", help="seconds to collect statuses"
    )
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from schemas.experiment import load_experiment

    console = Console()
    experiment = load_experiment(args.experiment) if args.experiment else None
    session = open_session(args, stop_on_signals())
    if session is None:
        return 0
    with session:
        result = control.issue(
            session,
            args.action,
            federation=args.federation,
            experiment=experiment,
            reference=args.reference,
            start_in=args.start_in,
            wait=args.wait,
            discover=args.discover,
            progress=console.print,
        )
    table = Table(title=f"fedlab ctl {args.action} ({result.elapsed:.2f} s)")
    table.add_column("agent")
    table.add_column("mode")
    for agent, mode in result.modes.items():
        table.add_row(agent, mode)
    console.print(table)
    return 0 if result.ok else 1

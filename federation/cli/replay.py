"""``fedlab replay RUN.mcap --agent LAB/NAME [--as LAB/NAME2]``: a recorded agent's
poses published on a live federation at their recorded run time (a ghost), synced with
the live run's reference and stamped on reference time; marked a replay in its status.

Parses and calls :func:`federation.runtime.replay.replay`; a refusal (a live agent with
the name, a real platform's identity) exits with code 2 and says why.
"""

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
    agent_id,
    open_session,
    positive,
    stop_on_signals,
)

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    """Add the ``replay`` command."""
    p = sub.add_parser(
        "replay",
        help="publish a recorded agent's poses on a live run at their recorded run time",
        formatter_class=Formatter,
        description=(
            "Play one agent's recorded poses (a per-agent recording or a merged file) into a\n"
            "live federation: each pose is published when the live run's run time reaches\n"
            "its recorded run time, stamped on the live reference clock (synced as agents\n"
            "do). It waits for a run to be announced by the live agents' status, plays from\n"
            "the run's present (from 0 if it waits before the start), and stops when the\n"
            "recording ends, the run is aborted or done, or on SIGINT/SIGTERM (exit 0).\n"
            "Its status says platform replay:FILE and carries a replay field.\n"
            "Refused (exit 2) if an agent with the name is live, or if it would take a\n"
            "real (hardware) platform's identity."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab replay runs/r1/kiruna-knatte.mcap --agent kiruna/knatte -e tcp/ROUTER:7447\n"
            "  fedlab replay runs/r1/merged.mcap --agent kiruna/knatte --as kiruna/ghost"
        ),
    )
    p.add_argument("file", type=Path, metavar="RUN.mcap", help="a recording or a merged file")
    p.add_argument(
        "--agent", type=agent_id, required=True, metavar="LAB/NAME", help="the recorded agent"
    )
    p.add_argument(
        "--as", dest="as_name", type=agent_id, default=None, metavar="LAB/NAME2",
        help="the name it is published under (default: the recorded agent's)",
    )  # fmt: skip
    p.add_argument(
        "--as-platform", default=None, metavar="SPEC",
        help="the platform the --as name's own config says (serial:PORT is refused)",
    )  # fmt: skip
    p.add_argument(
        "--max-bound", type=positive, default=0.05, metavar="S",
        help="a pose is withheld while the reference clock's error bound exceeds S seconds",
    )  # fmt: skip
    add_federation_flag(p)
    add_timeout_flag(p)
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Replay; print why it ended."""
    from federation.runtime.replay import replay

    if not args.file.is_file():
        print(f"fedlab replay: error: {args.file}: no such file", file=sys.stderr)
        return 2
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    with session:
        try:
            ended = replay(
                session, args.federation, args.file, args.agent, stop, args.as_name,
                args.as_platform, args.max_bound,
            )  # fmt: skip
        except ValueError as error:
            print(f"fedlab replay: {error}", file=sys.stderr)
            return 2
    print(f"replay of {args.agent} ended: {ended}")
    return 0

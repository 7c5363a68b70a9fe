"""``fedlab demo``: the paper's experiment on this machine, then its report."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

from federation.cli.common import Formatter, Subparsers, nonnegative, positive
from federation.core import paper

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    delay_ms = paper.ONE_WAY_DELAY * 1e3
    p = sub.add_parser(
        "demo",
        help=f"the paper's experiment on this machine: two labs, a {delay_ms:g} ms link, report",
        formatter_class=Formatter,
        description=textwrap.fill(
            "Two lab routers (kiruna listening, rome dialling it through a link emulator with"
            f" the paper's ~{delay_ms:g} ms one-way delay), a simulated KNATTE leading and a"
            f" simulated PINOCCHIO following with its clock {paper.CLOCK_OFFSET} s off; a"
            f" synchronized start, the paper's maneuver ({paper.MANEUVER_STILL:g} s still,"
            f" {paper.MANEUVER_AMPLITUDE_DEG:g} degrees and back in {paper.MANEUVER_DURATION:g} s),"
            " then the report (report.md, summary.json, figures) beside the paper's numbers.",
            width=88,
        ),
        epilog="Example: fedlab demo --duration 75 --out runs/demo",
    )
    p.add_argument(
        "--duration",
        type=positive,
        default=75.0,
        metavar="S",
        help="seconds of run after the start",
    )
    p.add_argument(
        "--delay-ms",
        type=nonnegative,
        default=delay_ms,
        metavar="MS",
        help="one-way delay of the lab link",
    )
    p.add_argument("--out", type=Path, default=Path("runs/demo"), metavar="DIR", help="run folder")
    p.add_argument(
        "--clock-offset",
        type=float,
        default=paper.CLOCK_OFFSET,
        metavar="S",
        help="follower's clock skew",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from federation.fleet.demo import run_demo

    return run_demo(
        duration=args.duration, out=args.out, delay_ms=args.delay_ms, clock_offset=args.clock_offset
    )

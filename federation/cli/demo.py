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
            " then the run merged into one file on reference time (merged.mcap and its"
            " Foxglove layout) and the report from it (report.md, summary.json, figures)"
            " beside the paper's numbers.",
            width=88,
        ),
        epilog=(
            "Examples:\n  fedlab demo --duration 75 --out runs/demo\n"
            "  fedlab demo --scenario formation --delay-ms 250 --out runs/formation-250\n"
            "  fedlab demo --scenario docking --seed 3 --out runs/docking-3"
        ),
    )
    p.add_argument(
        "--scenario",
        choices=["attitude", "formation", "docking"],
        default="attitude",
        help="attitude: the paper's experiment; formation: three labs keep a formation "
        "(deploy/experiments/formation.toml); docking: rome's PINOCCHIO docks with kiruna's "
        "KNATTE from emulated relative measurements (deploy/experiments/docking.toml)",
    )
    p.add_argument(
        "--duration",
        type=positive,
        default=None,
        metavar="S",
        help="seconds of run after the start (attitude: 75; else the experiment file's)",
    )
    p.add_argument(
        "--no-latency-compensation",
        dest="latency_compensation",
        action="store_false",
        help="formation, docking: use the others' poses as received, not dead-reckoned",
    )
    p.add_argument("--seed", type=int, default=0, help="formation, docking: seed of the noise")
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
    from federation.fleet.demo import run_demo, run_scenario_demo

    if args.scenario != "attitude":
        return run_scenario_demo(
            args.scenario,
            args.out,
            duration=args.duration,
            delay_ms=args.delay_ms,
            compensate=args.latency_compensation,
            seed=args.seed,
        )
    return run_demo(
        duration=75.0 if args.duration is None else args.duration,
        out=args.out,
        delay_ms=args.delay_ms,
        clock_offset=args.clock_offset,
    )

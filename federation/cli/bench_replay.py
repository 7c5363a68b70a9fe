"""``fedlab bench replay``: a follower flies the paper's whole maneuver against a live
leader, then against its replay (``fedlab replay``); the ratio of the two heading RMS
errors. Parses, runs :mod:`federation.bench.replay`, prints a table (or ``--json``) and
exits 1 when a repeat failed or its ratio exceeds the bound.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from federation.bench import replay
from federation.cli.common import Formatter, Subparsers, count, nonnegative

__all__ = ["add_replay", "run_replay"]


def add_replay(benches: Subparsers) -> None:
    p = benches.add_parser(
        "replay",
        help="a follower's heading error against a replayed leader over a live one's",
        formatter_class=Formatter,
        description=(
            "Real processes on loopback, per repeat: a router, the leader kiruna/knatte and\n"
            "the follower rome/pinocchio (through a link emulator with the paper's one-way\n"
            "delay) fly the paper's whole maneuver, recorded; then a fresh follower flies it\n"
            "against the leader's replay (fedlab replay). The follower's heading RMS error\n"
            "over the maneuver, live and replayed, and their ratio; exit 1 if a repeat\n"
            f"failed or its ratio exceeds {replay.BOUND:g}. About 3 minutes a repeat."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab bench replay --repeats 1\n"
            "  fedlab bench replay --repeats 3 --json-out benchmarks/replay-paper.json"
        ),
    )
    p.add_argument(
        "--repeats", type=count, default=3, metavar="N", help="repeats, one after another"
    )
    p.add_argument(
        "--delay-ms", type=nonnegative, default=replay.DELAY_MS, metavar="MS",
        help="one-way delay of the follower's link (0: it dials the router directly)",
    )  # fmt: skip
    p.add_argument(
        "--work-dir", type=Path, default=None, metavar="DIR",
        help="keep each repeat's recordings, status files and logs here (default: a "
        "temporary folder, removed at the end)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--json-out", type=Path, metavar="FILE", help="also write the JSON to FILE")
    p.add_argument(
        "--maneuver-seconds", type=float, default=None, metavar="S",
        help="fly a rotation of S s after a 0.5 s still phase instead of the paper's "
        "maneuver (a quick check of the machinery; its figures are not the benchmark's)",
    )  # fmt: skip
    p.add_argument(
        "--sync-window", type=float, default=None, metavar="S",
        help="the agents' sync window (s; default: the paper's sync phase)",
    )  # fmt: skip


def _command(args: argparse.Namespace) -> str:
    words = ["fedlab bench replay", f"--repeats {args.repeats}"]
    if args.delay_ms != replay.DELAY_MS:
        words.append(f"--delay-ms {args.delay_ms:g}")
    if args.maneuver_seconds is not None:
        words.append(f"--maneuver-seconds {args.maneuver_seconds:g}")
    if args.sync_window is not None:
        words.append(f"--sync-window {args.sync_window:g}")
    if args.json_out is not None:
        words.append(f"--json-out {args.json_out}")
    return " ".join(words)


def run_replay(args: argparse.Namespace) -> int:
    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        result = replay.run(
            args.repeats,
            args.work_dir,
            args.maneuver_seconds,
            args.delay_ms,
            progress,
            args.sync_window,
        )
    except ValueError as error:
        print(f"fedlab bench replay: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fedlab bench replay: interrupted; every process stopped", file=sys.stderr)
        return 130
    result = {"command": _command(args), **result}
    text = json.dumps(result, indent=1)
    if args.json_out is not None:
        args.json_out.write_text(text + "\n", encoding="utf-8")
    if args.json:
        print(text)
    else:
        print(f"{'repeat':>6} {'live (deg)':>11} {'replayed (deg)':>15} {'ratio':>7}")
        for r in result["repeats"]:
            if "ratio" in r:
                print(
                    f"{r['repeat']:>6} {r['rms_live_deg']:>11.4f} "
                    f"{r['rms_replayed_deg']:>15.4f} {r['ratio']:>7.3f}"
                )
            else:
                print(f"{r['repeat']:>6} failed: {r['error'].splitlines()[0]}")
    bad = replay.failures(result)
    for why in bad:
        print(f"fedlab bench replay: {why}", file=sys.stderr)
    return 1 if bad else 0

"""``fedlab merge RUN_DIR``: one MCAP for the whole run, on reference time, and its
Foxglove layout.

Opens no Zenoh session: it reads the run directory's recordings and calls
:func:`federation.report.merge.write_merged`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from federation.cli.common import Formatter, Subparsers

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    """Add the ``merge`` command."""
    p = sub.add_parser(
        "merge",
        help="merge a run's recordings into one MCAP on reference time, for Foxglove",
        formatter_class=Formatter,
        description=(
            "Read every agent's MCAP recording in RUN_DIR and write one MCAP whose log time\n"
            "is the run's reference time (never a host's wall clock), its epoch the run's\n"
            "start in UTC with its uncertainty; each JSON message gains t_ref and\n"
            "t_ref_bound (s), topics are namespaced /LAB/NAME/..., poses, events, holds and\n"
            "work areas are also in Foxglove's types, and a Foxglove layout is written\n"
            "beside it (NAME.layout.json). An agent's later segments (LAB-NAME.seg2.mcap...,\n"
            "recorded after a rejoin) are that agent's, on its topics, with the gap logged.\n"
            "fedlab report RUN_DIR then reads the merged file. Streams: memory does not grow\n"
            "with the run."
        ),
        epilog=(
            "Examples:\n  fedlab merge runs/demo\n  fedlab merge runs/collected --out /tmp/run.mcap"
        ),
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="folder of *.mcap recordings")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="FILE",
        help="merged file (default: RUN_DIR/merged.mcap)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Merge, then print what was written."""
    from federation.report.merge import write_merged

    start = time.monotonic()
    result, layout = write_merged(args.run_dir, args.out)
    took = time.monotonic() - start
    out = args.out or args.run_dir / "merged.mcap"
    bound = result.epoch.uncertainty
    print(
        f"merged {len(result.agents)} agents ({', '.join(result.agents)}) on the reference "
        f"clock of {result.reference}: {result.messages_out} messages in {took:.2f} s"
    )
    print(
        f"epoch (run start): {result.metadata()['epoch_utc'] or 'unknown'}"
        + ("" if bound is None else f" ± {bound * 1e3:.1f} ms")
    )
    for note in result.notes:
        print(f"note: {note}")
    print(f"wrote {out} and {layout}")
    return 0

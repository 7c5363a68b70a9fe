"""``fedlab report RUN_DIR``: report.md, summary.json and figures for a recorded run.

Opens no Zenoh session: it reads the run directory's recordings
(:func:`federation.report.write_report`) and prints the table beside the paper.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from federation.cli.common import Formatter, Subparsers

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    """Add the ``report`` command."""
    p = sub.add_parser(
        "report",
        help="write report.md, summary.json and figures for a recorded run",
        formatter_class=Formatter,
        description=(
            "Read every agent's MCAP recording in RUN_DIR (and run.json, if there) and write\n"
            "summary.json, PNG figures like the paper's and report.md setting the run beside\n"
            "the paper's numbers."
        ),
        epilog="Example:\n  fedlab report runs/demo\n  fedlab report runs/demo --out /tmp/report",
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="folder of *.mcap recordings")
    p.add_argument(
        "--out", type=Path, default=None, metavar="DIR", help="output folder (default: RUN_DIR)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the report into ``--out`` (default: RUN_DIR) and print the comparison table."""
    from rich.console import Console

    from federation.report import summary_table, write_report

    out = args.out or args.run_dir
    summary = write_report(args.run_dir, out)
    console = Console()
    console.print(
        summary_table(summary, f"fedlab report {args.run_dir}: this run beside the paper")
    )
    for note in summary["notes"]:
        console.print(f"[yellow]note:[/] {note}", highlight=False)
    console.print(f"wrote to {out}: {', '.join(summary['files'])}", highlight=False)
    return 0

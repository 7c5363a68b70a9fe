"""``fedlab report RUN``: report.md, summary.json and figures for a recorded run.

Opens no Zenoh session: it reads the run's merged file or its per-agent recordings
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
            "Read a recorded run and write summary.json, PNG figures like the paper's and\n"
            "report.md setting the run beside the paper's numbers.\n\n"
            "RUN is a run folder or a merged file (fedlab merge). In a run folder the report\n"
            "reads its merged file (merged.mcap, or its one merged file) when that was\n"
            "merged from the recordings the folder holds now (each one's name and size), so\n"
            "the figures, summary.json and the merged file are one source; otherwise every\n"
            "agent's MCAP recording (and run.json, if there). summary.json's source and\n"
            "report.md say which files were read."
        ),
        epilog=(
            "Examples:\n  fedlab report runs/demo\n  fedlab report runs/demo --out /tmp/report\n"
            "  fedlab report runs/demo/merged.mcap\n"
            "  fedlab report runs/demo --source recordings"
        ),
    )
    p.add_argument(
        "run_dir", type=Path, metavar="RUN", help="run folder, or a merged file (*.mcap)"
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="output folder (default: the run folder, or the merged file's folder)",
    )
    p.add_argument(
        "--source",
        choices=("auto", "merged", "recordings"),
        default="auto",
        help="files to read in a run folder: its merged file if current, else the "
        "recordings (auto); the merged file (merged); the per-agent recordings (recordings)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the report into ``--out`` (default: the run's folder) and print the
    comparison table."""
    from rich.console import Console

    from federation.report import summary_table, write_report

    out = args.out or (args.run_dir.parent if args.run_dir.is_file() else args.run_dir)
    summary = write_report(args.run_dir, out, source=args.source)
    console = Console()
    console.print(
        summary_table(summary, f"fedlab report {args.run_dir}: this run beside the paper")
    )
    # soft_wrap: a line naming files is never broken inside a path, so it can be copied.
    for note in summary["notes"]:
        console.print(f"[yellow]note:[/] {note}", highlight=False, soft_wrap=True)
    source = summary["source"]
    console.print(
        f"read {source['kind']}: {', '.join(source['files'])}", highlight=False, soft_wrap=True
    )
    console.print(f"wrote to {out}: {', '.join(summary['files'])}", highlight=False, soft_wrap=True)
    return 0

"""``fedlab schemas``: write or check the JSON Schemas of fedlab's messages and config files
(:mod:`schemas.export`; ``python -m schemas.export`` does the same), and the user guide's
generated reference pages (``--docs``: :mod:`federation.cli.reference`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from federation.cli.common import Formatter, Subparsers
from federation.core.counters import counters_table_markdown
from federation.core.holds import holds_table_markdown
from schemas import export

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "schemas",
        help="write or check the JSON Schemas of the messages and config files",
        formatter_class=Formatter,
        description=(
            "Write schemas/json/<Name>.schema.json (JSON Schema draft 2020-12) for every\n"
            "message and configuration model, so a client in another language can validate\n"
            "what it publishes and reads. With --check, write nothing and exit 1 if the\n"
            "files differ from the models."
        ),
        epilog=(
            "Examples:\n  fedlab schemas\n  fedlab schemas --check\n"
            "  fedlab schemas --holds > table.md   # docs/holds.md's table\n"
            "  fedlab schemas --counters > table.md   # docs/counters.md's table\n"
            "  fedlab schemas --docs            # docs/reference/: every command and config field\n"
            "  fedlab schemas --docs --check"
        ),
    )
    p.add_argument(
        "--out", type=Path, default=export.DEFAULT_DIR, metavar="DIR", help="where the files are"
    )
    p.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if the files are stale"
    )
    p.add_argument(
        "--holds",
        action="store_true",
        help="print the holds' table (docs/holds.md) from federation.core.holds and exit",
    )
    p.add_argument(
        "--counters",
        action="store_true",
        help="print the counters' table (docs/counters.md) from federation.core.counters and exit",
    )
    p.add_argument(
        "--docs",
        action="store_true",
        help="write the reference pages (every command, every config field) instead; "
        "with --check, exit 1 if they are stale",
    )
    p.add_argument(
        "--docs-dir",
        type=Path,
        default=Path("docs/reference"),
        metavar="DIR",
        help="where --docs writes",
    )
    p.set_defaults(func=run)


def _run_docs(args: argparse.Namespace) -> int:
    from federation.cli import reference  # imports every command's parser

    if args.check:
        stale = reference.check(args.docs_dir)
        if stale:
            print(
                f"stale reference pages in {args.docs_dir}: {', '.join(stale)}; "
                "run: fedlab schemas --docs",
                file=sys.stderr,
            )
            return 1
        print(f"{len(reference.PAGES)} reference pages in {args.docs_dir} match the code")
        return 0
    for path in reference.write(args.docs_dir):
        print(path)
    return 0


def run(args: argparse.Namespace) -> int:
    if args.docs:
        return _run_docs(args)
    if args.holds:
        print(holds_table_markdown(), end="")
        return 0
    if args.counters:
        print(counters_table_markdown(), end="")
        return 0
    if args.check:
        stale = export.check(args.out)
        if stale:
            print(
                f"stale JSON Schemas in {args.out}: {', '.join(stale)}; run: fedlab schemas",
                file=sys.stderr,
            )
            return 1
        print(f"{len(export.MODELS)} JSON Schemas in {args.out} match the models")
        return 0
    for path in export.export(args.out):
        print(path)
    return 0

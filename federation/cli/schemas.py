"""``fedlab schemas``: write or check the JSON Schemas of fedlab's messages and config files
(:mod:`schemas.export`; ``python -m schemas.export`` does the same)."""

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
            "  fedlab schemas --counters > table.md   # docs/counters.md's table"
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
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

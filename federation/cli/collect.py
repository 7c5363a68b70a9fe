"""``fedlab collect RUN_ID --out DIR``: every lab's recordings of a run, over the federation.

Parses, calls :func:`federation.runtime.collect.collect` and prints what was
fetched, resumed, fetched again and missing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from federation.cli.common import (
    Formatter,
    Subparsers,
    add_federation_flag,
    add_timeout_flag,
    add_zenoh_flags,
    open_session,
    run_id,
    stop_on_signals,
)

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "collect",
        help="fetch a run's recordings from every lab over the federation",
        formatter_class=Formatter,
        description=(
            "Ask every agent of the federation for its finished files of RUN_ID (recorded\n"
            "under its runs/<run-id>/), fetch them in chunks (each chunk's SHA-256 checked,\n"
            "a bad one fetched again; the whole file checked against the agent's manifest)\n"
            "into DIR, ready for fedlab report DIR. Run it again to resume: complete files\n"
            "are kept, partial ones (.part) continue where they stopped. Exit code 1 if a\n"
            "participant (with --experiment) has no such run or a file failed. A recording\n"
            "that is not whole (its agent was killed mid-run and recovered it when started\n"
            "again, it reached record_max_mb, or a write failed) comes with\n"
            "<lab>-<name>.incomplete.json, and what it misses is printed."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab collect attitude-tracking-20250101T120000Z --out runs/collected \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab report runs/collected"
        ),
    )
    p.add_argument("run_id", type=run_id, metavar="RUN_ID", help="the run (ctl start names it)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write to")
    p.add_argument(
        "--experiment", type=Path, metavar="FILE", help="its participants must all answer"
    )
    add_federation_flag(p, "federation name (an experiment's own wins)")
    p.add_argument(
        "--retries",
        type=int,
        default=5,
        metavar="N",
        help="fetches of a bad chunk before giving up",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    add_timeout_flag(p)
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.text import Text

    from federation.report.completion import summary_lines
    from federation.runtime.collect import collect, describe
    from federation.runtime.monitor import printable
    from schemas.experiment import load_experiment

    console = Console(stderr=args.json)
    experiment = load_experiment(args.experiment) if args.experiment else None
    federation = experiment.federation if experiment else args.federation
    expected = {p.agent for p in experiment.participants} if experiment else None
    session = open_session(args, stop_on_signals())
    if session is None:
        return 0
    with session:
        result = collect(
            session, federation, args.run_id, args.out, expected=expected,
            timeout=args.timeout, retries=args.retries,
            progress=lambda line: console.print(Text(printable(line))),
        )  # fmt: skip
    parts, duration = completions(args.out, expected)
    if args.json:
        print(json.dumps(describe(result) | {"participants": parts}, indent=1))
    else:
        # What agents sent (error texts, file names) is printed as text, never as markup,
        # and without control characters.
        for why, n in sorted(result.refetched.items()):
            console.print(Text(printable(f"fetched again: {n} chunk(s), {why}")))
        if result.resumed:
            console.print(f"resumed: {', '.join(result.resumed)}")
        if result.skipped:
            console.print(f"already complete: {', '.join(result.skipped)}")
        for agent in result.missing:
            console.print(Text(f"{agent}: no finished run {args.run_id}", style="red"))
        for error in result.errors:
            console.print(Text(printable(error), style="red"))
        for agent, what in sorted(result.incomplete.items()):  # collected, but not whole
            console.print(Text(printable(f"{agent}: {what}"), style="yellow"))
        for line in summary_lines(parts, duration):  # how far each flew, and if it finished
            console.print(Text(printable(line)))
        console.print(f"{result.bytes_fetched} bytes fetched into {args.out}")
    return 0 if result.ok else 1


def completions(out: Path, expected: set[str] | None) -> tuple[dict[str, Any], float | None]:
    """Per participant of the run collected into ``out``: the run time it reached and
    whether it completed (:mod:`federation.report.completion`); the run's duration."""
    from federation.report.completion import NO_RECORDING, participants
    from federation.report.load import load_run
    from federation.report.summary import run_description
    from schemas.config import ConfigError

    try:
        run = load_run(out)
    except ConfigError:  # nothing collected: no recording to read
        run = None
    parts = {} if run is None else participants(run)
    for agent in sorted(expected or ()):
        parts.setdefault(agent, dict(NO_RECORDING))
    duration = None if run is None else run_description(run)["run_duration_s"]
    return dict(sorted(parts.items())), duration

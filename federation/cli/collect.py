"""``fedlab collect RUN_ID --out DIR``: every lab's recordings of a run, over the federation.

Parses, calls :func:`federation.runtime.collect.collect` and prints what was
fetched, resumed, fetched again and missing; then merges what it gathered into
``DIR/merged.mcap`` (:func:`federation.report.merge.merge_folder`) unless
``--no-merge``.
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
            "are kept, partial ones (.part) continue where they stopped. Then it merges what\n"
            "it gathered into DIR/merged.mcap on reference time, with its Foxglove layout\n"
            "DIR/merged.layout.json (as fedlab merge DIR; --no-merge skips it), which\n"
            "fedlab report DIR then reads. A merge that fails is printed with why; the\n"
            "recordings stay as fetched. Exit code 1 if a participant (with --experiment)\n"
            "has no such run, a file failed or the merge failed. A recording\n"
            "that is not whole (its agent was killed mid-run and recovered it when started\n"
            "again, it reached record_max_mb, or a write failed) comes with\n"
            "<lab>-<name>.incomplete.json, and what it misses is printed."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab collect attitude-tracking-20250101T120000Z --out runs/collected \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab report runs/collected\n"
            "  fedlab collect attitude-tracking-20250101T120000Z --out runs/collected --no-merge"
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
    p.add_argument(
        "--no-merge",
        action="store_true",
        help="keep the recordings only: no DIR/merged.mcap (fedlab merge DIR writes it later)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    add_timeout_flag(p)
    add_zenoh_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.text import Text

    from federation.report.completion import summary_lines
    from federation.report.merge import merge_folder
    from federation.runtime.collect import collect, describe
    from federation.runtime.monitor import printable
    from schemas.experiment import load_experiment

    # soft_wrap: every line is text, and one naming a path is never broken inside it.
    console = Console(stderr=args.json, soft_wrap=True)
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
    gathered = args.out.is_dir() and any(args.out.glob("*.mcap"))
    merged = merge_folder(args.out) if gathered and not args.no_merge else None
    if args.json:
        described = describe(result) | {"participants": parts, "merged": merged}
        print(json.dumps(described, indent=1))
    else:
        _print(console, result, args, summary_lines(parts, duration), merged)
    failed = merged is not None and "error" in merged
    return 0 if result.ok and not failed else 1


def _print(
    console: Any,
    result: Any,
    args: argparse.Namespace,
    participants: list[str],
    merged: dict[str, Any] | None,
) -> None:
    """The collection as text: what was fetched again, resumed, missing and failed, how
    far each participant flew, and the merge."""
    from rich.text import Text

    from federation.runtime.monitor import printable

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
    for line in participants:  # how far each flew, and if it finished
        console.print(Text(printable(line)))
    console.print(f"{result.bytes_fetched} bytes fetched into {args.out}")
    for line, style in merge_lines(merged):
        console.print(Text(printable(line), style=style))


def merge_lines(merged: dict[str, Any] | None) -> list[tuple[str, str]]:
    """What the merge after the collect wrote, or why it failed, as (line, style)."""
    if merged is None:
        return []
    if "error" in merged:
        kept = ", ".join(merged["kept"]) or "none"
        return [
            (f"merge failed: {merged['error']}", "red"),
            (f"the recordings are kept as fetched ({kept}); fedlab report reads them", "red"),
        ]
    lines = [(f"note: {note}", "yellow") for note in merged["notes"]]
    lines.append((
        f"merged {len(merged['agents'])} agents on the reference clock of "
        f"{merged['reference']}: {merged['file']} (Foxglove layout {merged['layout']})", "",
    ))  # fmt: skip
    return lines


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

"""Mark a cosmic-ray session's mutants of type annotations as skipped, and sum a session up.

    python tests/mutation/skip_annotations.py SESSION   # after init: skip them
    python tests/mutation/skip_annotations.py --summary SESSION

A mutant inside an annotation (``float | None`` made ``float + None``, say) is
equivalent in a module that says ``from __future__ import annotations``: the
annotation stays a string nobody evaluates (mypy rejects it; no test can). Each is
skipped, not run, and counted apart (docs/mutation.md). A module without that import
gets no mutant skipped: there an annotation is evaluated, and its mutants are run.
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

from cosmic_ray.work_db import WorkDB, use_db
from cosmic_ray.work_item import WorkerOutcome, WorkResult

REASON = "skipped: in a type annotation, never evaluated (from __future__ import annotations)"

Span = tuple[tuple[int, int], tuple[int, int]]


def annotation_spans(source: str) -> list[Span]:
    """(start, end) of every annotation, as (line from 1, column from 0)."""
    tree = ast.parse(source)
    postponed = any(
        isinstance(node, ast.ImportFrom)
        and node.module == "__future__"
        and any(alias.name == "annotations" for alias in node.names)
        for node in tree.body
    )
    if not postponed:
        return []
    found: list[ast.expr] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.AnnAssign | ast.arg) and node.annotation is not None:
            found.append(node.annotation)
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.returns:
            found.append(node.returns)
    lines = source.splitlines()

    def column(line: int, offset: int) -> int:  # ast counts UTF-8 bytes, parso characters
        return len(lines[line - 1].encode()[:offset].decode())

    return [
        (
            (a.lineno, column(a.lineno, a.col_offset)),
            (a.end_lineno or a.lineno, column(a.end_lineno or a.lineno, a.end_col_offset or 0)),
        )
        for a in found
    ]


def skip(db: WorkDB) -> int:
    spans: dict[str, list[Span]] = {}
    skipped = 0
    for item in db.work_items:
        (mutation,) = item.mutations
        path = str(mutation.module_path)
        if path not in spans:
            spans[path] = annotation_spans(Path(path).read_text(encoding="utf-8"))
        start, end = tuple(mutation.start_pos), tuple(mutation.end_pos)
        if any(a <= start and end <= b for a, b in spans[path]):
            db.set_result(
                item.job_id, WorkResult(worker_outcome=WorkerOutcome.SKIPPED, output=REASON)
            )
            skipped += 1
    return skipped


def summary(db: WorkDB) -> str:
    """Total, skipped (annotations), killed, survived, and the share of the run killed."""
    outcomes: Counter[str] = Counter()
    for _, result in db.results:
        if result.worker_outcome != WorkerOutcome.NORMAL:
            outcomes[str(result.worker_outcome.value)] += 1
        else:  # a timeout is killed too (a mutant that loops)
            outcomes[str(result.test_outcome.value if result.test_outcome else None)] += 1
    total = db.num_work_items
    run = outcomes["killed"] + outcomes["survived"]
    share = 100.0 * outcomes["killed"] / run if run else 0.0
    rest = "".join(
        f", {n} {k}" for k, n in outcomes.items() if k not in ("skipped", "killed", "survived")
    )
    pending = total - sum(outcomes.values())
    return (
        f"{total} mutants: {outcomes['skipped']} in annotations (skipped), {run} run: "
        f"{outcomes['killed']} killed, {outcomes['survived']} survived ({share:.1f} % killed)"
        f"{rest}{f', {pending} pending' if pending else ''}"
    )


def main(argv: list[str]) -> int:
    if argv[:1] == ["--summary"]:
        with use_db(argv[1], WorkDB.Mode.open) as db:
            print(summary(db))
        return 0
    (session,) = argv
    with use_db(session, WorkDB.Mode.open) as db:
        print(f"{skip(db)} mutants in annotations skipped")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

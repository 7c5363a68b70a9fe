"""Reports from a run's recordings: loading, analysis, summary, figures, markdown.

``fedlab report RUN_DIR`` (:mod:`federation.cli.report`) calls :func:`write_report`,
which writes into a folder:

- ``summary.json``: every figure of the run, each key naming its unit
  (:mod:`federation.report.summary`, measured by :mod:`federation.report.analysis`
  from the run's merged file, :mod:`federation.report.frommerged`, or its per-agent
  recordings, :mod:`federation.report.load`; ``source`` says which);
- PNG figures like the source paper's, figures 8 to 11 (:mod:`federation.report.figures`);
- ``report.md``: the run beside the source paper (``docs/paper.md``)
  (:mod:`federation.report.markdown`).

:mod:`federation.report.status` reads status lines and the ground truth one host gives.

Rule: reads files only; no Zenoh, no argparse, no :mod:`federation.cli`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from federation.core import paper
from federation.report.figures import write_figures
from federation.report.frommerged import Source, load_merged, open_run
from federation.report.load import Run, load_run
from federation.report.markdown import markdown
from federation.report.scenarios import markdown_section, scenario_summary, write_scenario_figures
from federation.report.summary import comparison_rows, source_of, summarize, summary_table

__all__ = [
    "Run",
    "Source",
    "comparison_rows",
    "load_merged",
    "load_run",
    "open_run",
    "summarize",
    "summary_table",
    "write_report",
]


def write_report(
    run: Run | str | Path,
    out: str | Path | None = None,
    sync_phase: float = paper.SYNC_PHASE,
    source: Source = "auto",
) -> dict[str, Any]:
    """Write summary.json, the figures and report.md into ``out``.

    Parameters
    ----------
    run
        A loaded run, or its folder or merged file (:func:`open_run`).
    out
        Output folder, created if needed; default: the run directory.
    source
        Which files of a run folder to read (:data:`Source`): by default its merged
        file when it was merged from the recordings there, else the recordings.
    sync_phase
        Seconds of exchanges before the clock estimate is scored against the truth.

    Returns
    -------
    dict
        The summary, with ``figures`` (name -> file) and ``files`` (every file
        written, in ``out``).
    """
    if not isinstance(run, Run):
        run = open_run(run, source)
    out = Path(out if out is not None else run.directory)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(run, sync_phase)
    scenario = scenario_summary(run)  # formation, docking, workspace
    notes = summary["notes"] + scenario.pop("notes", [])  # the run's notes stay
    summary |= scenario
    summary["notes"] = notes
    summary["source"] = source_of(run)
    figures = write_figures(run, summary, out, sync_phase)
    figures |= write_scenario_figures(run, summary, out)
    summary["figures"] = {k: p.name for k, p in figures.items()}
    summary["files"] = ["summary.json", "report.md", *(p.name for p in figures.values())]
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    report = markdown(summary, run.meta) + markdown_section(summary)
    (out / "report.md").write_text(report, encoding="utf-8")
    return summary

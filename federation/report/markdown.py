"""``report.md``: a run set beside the source paper, in Markdown.

The text is built from the summary alone (:func:`federation.report.summary.summarize`,
with the ``figures`` :func:`federation.report.figures.write_figures` drew) and the
demo's ``run.json``; it names the source paper by ``docs/paper.md``, the one place
that describes it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from federation.core import paper
from federation.report.summary import comparison_rows

__all__ = ["markdown"]


CLOCKS_NOTE = (
    "Clock offset and drift here are the skew given to an agent's clock (`--clock-offset`, "
    "`--clock-drift-ppm`; none on real hardware). Each agent's clock starts at an "
    "arbitrary origin anyway, so offsets of tens of seconds between agents, even on one "
    "host, are expected: synchronization measures them (the tables below)."
)
"""The report's paragraph on clocks, under the table of agents."""


def _number(value: Any, spec: str = "g") -> str:
    """A number as the report prints it (``spec``); "unknown" for anything else."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "unknown"
    return format(value, spec)


def _emulated(meta: dict[str, Any] | None) -> str:
    """One sentence on the emulated link, from run.json."""
    if meta is None:
        return "Unknown: the run directory has no run.json."
    link = meta.get("link")
    if not link:
        return "No network emulation: the agents talked over loopback."
    delay, jitter = link.get("delay_ms"), link.get("jitter_ms")
    extra = {k: v for k, v in link.items() if k not in ("delay_ms", "jitter_ms")}
    text = f"A link with {delay} ms one-way delay"
    text += f" and {jitter} ms jitter" if jitter is not None else ""
    if extra:
        text += " (" + ", ".join(f"{k} {v}" for k, v in extra.items()) + ")"
    return text + " between the labs' routers."


def _completion_lines(described: dict[str, Any]) -> list[str]:
    """Whether the run completed, and per participant the run time it reached: a
    participant that stopped early is never said to have completed it."""
    parts = described.get("participants") or {}
    duration = described.get("run_duration_s")
    of = f" its {duration:g} s of run time" if duration is not None else " its run"
    if not parts:
        return []
    if described.get("complete"):
        return [f"Every participant completed{of}.", ""]
    lines = [
        f"**Incomplete run**: not every participant completed{of}; figures cover what each "
        "recorded.",
        "",
        "| participant | run time reached (s) | completed | how its run ended | segments "
        "| gaps (run time, s) |",
        "|---|---:|---|---|---:|---|",
    ]
    for agent, part in parts.items():
        reached = part.get("reached_s")
        holes = ", ".join(f"{a:.1f} to {b:.1f}" for a, b in part.get("gaps_s") or []) or "-"
        lines.append(
            f"| {agent} | {'-' if reached is None else f'{reached:.1f}'} "
            f"| {'yes' if part.get('complete') else 'no'} | {_ENDED.get(part.get('ended'), '?')} "
            f"| {len(part.get('segments_s') or [])} | {holes} |"
        )
    return [*lines, ""]


_ENDED = {
    "done": "done: its run time reached the duration",
    "aborted": "aborted",
    "stopped early": "stopped early: no end recorded (its process stopped or was killed)",
    "no recording": "no recording",
}


def _run_lines(described: dict[str, Any]) -> list[str]:
    """Experiment, run id, date, versions, completion and each agent's command line."""
    if not described.get("run_id"):
        return _completion_lines(described)
    versions = described.get("versions") or {}
    lines = [
        f"Experiment **{described.get('experiment') or '?'}**, run `{described['run_id']}`, "
        f"started {described.get('utc_start') or '?'} (UTC). fedlab "
        f"{versions.get('fedlab_version') or '?'}, Zenoh {versions.get('zenoh_version') or '?'}, "
        f"Python {versions.get('python_version') or '?'}, commit "
        f"`{(versions.get('git_commit') or 'none')[:12]}`.",
        "",
    ]
    reached, duration = described.get("run_time_reached_s"), described.get("run_duration_s")
    if described.get("truncated"):
        lines += [
            f"**Truncated run**: run time reached {reached:.1f} s of the {duration:g} s planned "
            "(aborted or stopped early).",
            "",
        ]
    lines += _completion_lines(described)
    for agent, command in sorted((described.get("command_lines") or {}).items()):
        host = (described.get("hosts") or {}).get(agent) or "?"
        lines.append(f"- {agent} on {host}: `{command}`")
    return [*lines, ""]


def _headline(followers: list[dict[str, Any]]) -> list[str]:
    """Each follower's heading error against the leader's actual heading."""
    rows = [f for f in followers if f.get("heading_error_vs_leader_rms_deg") is not None]
    if not rows:
        return []
    lines = [
        "## Headline: heading error against the leader",
        "",
        "Each follower's heading minus the leader's actual heading at the same reference "
        "time, while the run ran (figure: heading, bottom panel).",
        "",
        "| follower | leader | latency compensation | RMS (deg) | max (deg) |",
        "|---|---|---|---:|---:|",
    ]
    for f in rows:
        comp = f.get("latency_compensation")
        lines.append(
            f"| {f['follower']} | {f['leader']} | "
            f"{'?' if comp is None else 'with' if comp else 'without'} | "
            f"{f['heading_error_vs_leader_rms_deg']:.3f} | "
            f"{f['heading_error_vs_leader_max_deg']:.3f} |"
        )
    return [*lines, ""]


def _source_line(source: dict[str, Any]) -> str:
    """Which files every figure here was computed from."""
    files = ", ".join(f"`{name}`" for name in source.get("files") or []) or "unknown"
    if source.get("kind") == "merged":
        return (
            f"Source: the merged run {files} (fedlab merge, on reference time): the figures, "
            "summary.json and that file are one source. `--source recordings` reads the "
            "per-agent recordings instead."
        )
    return (
        f"Source: the per-agent recordings {files}. Once the run is merged "
        "(fedlab merge RUN_DIR), the report reads the merged file."
    )


def markdown(summary: dict[str, Any], meta: dict[str, Any] | None) -> str:
    """report.md: the run, the table beside the paper, the figures and the notes."""
    run_name = Path(summary["run_dir"]).name or summary["run_dir"]
    described = summary.get("run") or {}
    lines = [f"# fedlab run report: {described.get('run_id') or run_name}", ""]
    lines += _run_lines(described)
    lines += [_source_line(summary.get("source") or {}), ""]
    lines += _headline(summary.get("followers") or [])
    if summary.get("command"):
        lines += [f"Command: `{summary['command']}`", ""]
    if summary.get("duration_s") is not None:
        lines += [f"Duration: {summary['duration_s']} s.", ""]
    lines += ["## What was emulated", "", _emulated(meta), ""]
    info = (meta or {}).get("agents") or {}
    lines += [
        "| agent | role | platform | follows | latency compensation | clock offset (s) "
        "| clock drift (ppm) | recording |",
        "|---|---|---|---|---|---|---|---|",
    ]
    settings = described.get("clock_settings") or {}
    unknown = False
    for name, a in summary["agents"].items():
        i = {**(settings.get(name) or {}), **(info.get(name) or {})}  # run.json's first
        offset, drift = _number(i.get("clock_offset"), ".3f"), _number(i.get("clock_drift_ppm"))
        unknown = unknown or "unknown" in (offset, drift)
        comp = a["latency_compensation"]
        lines.append(
            f"| {name} | {a['role'] or '?'} | {a['platform'] or '?'} | {a['follow'] or '-'} "
            f"| {'-' if comp is None else ('on' if comp else 'off')} "
            f"| {offset} | {drift} | {a['recording']} |"
        )
    lines += ["", CLOCKS_NOTE]
    if unknown:
        lines += [
            "",
            "Unknown: neither a run.json nor the agent's recorded settings say what skew it "
            "was given (a recording made without a runs folder holds no settings).",
        ]
    lines += [
        "",
        "## This run beside the paper",
        "",
        "The paper's figures come from the source paper (docs/paper.md): its validation (600 s "
        "over the internet) and its hardware run (figures 8-11). Its clock offset, "
        f"{paper.CLOCK_OFFSET:.3f} s, is the gap between its two labs' clocks, set beside this "
        "run's for scale: an offset is whatever the clocks' origins make it, and what sync is "
        "judged by is how steady its estimate is (offset std) and its error against the truth.",
        "",
        "| figure | pair or agent | this run | paper |",
        "|---|---|---:|---:|",
    ]
    for row in comparison_rows(summary):
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |")
    figures = summary.get("figures", {})
    lines += ["", "## Clock synchronization (figures 8, 9 and 11)", ""]
    lines += [
        "Each exchange gives an offset (Eq. 4) and a delay (Eq. 3); the line is the client's "
        "filtered estimate, the dashed line the truth from the shared host clock. Truth here "
        "cannot show path asymmetry: over a real path the estimate is also off by half of it.",
        "",
    ]
    for s in summary["sync"]:
        key = f"sync {s['client']} {s['peer']}"
        if key in figures:
            lines += [f"![sync of {s['client']} with {s['peer']}]({figures[key]})", ""]
    lines += ["## Heading (figure 10)", ""]
    if "heading" in figures:
        lines += [
            "Every heading on reference time (the leader's clock). Lag: the shift of the peak "
            "Pearson correlation between the follower's and the leader's heading.",
            "",
            f"![heading]({figures['heading']})",
            "",
            "## Sent vs received heading",
            "",
            "Separation: the time shift that best aligns a series with the sent heading "
            "(least squares over the maneuver). The received heading trails by the one-way "
            "delay; a latency-compensated follower's guidance reference should not trail at all.",
            "",
            f"![sent vs received heading]({figures['sent_vs_received']})",
            "",
        ]
    else:
        lines += ["No follower with a recorded leader: no heading figures.", ""]
    if summary["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in summary["notes"]] + [""]
    return "\n".join(lines)

"""``summary.json`` and the table beside the paper.

The summary holds every figure of a run, each key naming its unit (``_s``,
``_deg``, ``_count``); :func:`comparison_rows` sets them beside the source
paper's (``docs/paper.md``, numbers from :mod:`federation.core.paper`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from federation.core import paper
from federation.core.channels import Channel
from federation.report.analysis import (
    SHIFT_MAX_S,
    Array,
    Follow,
    SyncPair,
    best_shift,
    follows,
    heading_error,
    heading_rms_deg,
    heading_source,
    sync_pairs,
    xcorr_lag,
)
from federation.report.completion import incomplete_notes, participants
from federation.report.load import Run

__all__ = [
    "PAPER",
    "comparison_rows",
    "compensation_label",
    "fmt",
    "follow_summary",
    "source_of",
    "summarize",
    "summary_table",
    "sync_summary",
]


def _ms(low_high: tuple[float, float]) -> tuple[float, float]:
    """A (low, high) range in seconds, in milliseconds."""
    low, high = low_high
    return low * 1e3, high * 1e3


# The source paper's figures (docs/paper.md): (low, high) in the unit of the key.
PAPER: dict[str, tuple[float, float]] = {
    "offset_std_ms": _ms(paper.OFFSET_STD),
    "delay_median_ms": _ms(paper.ONE_WAY_DELAY_MEDIAN),
    "delay_std_ms": _ms(paper.ONE_WAY_DELAY_STD),
    "separation_ms": _ms(paper.RECEIVED_BEHIND_SENT),
    "lag_s": paper.FOLLOWER_LAG,
}


# -- summary.json ------------------------------------------------------------------------
def sync_summary(
    pair: SyncPair, emulated_delay_s: float | None = None, sync_phase: float = paper.SYNC_PHASE
) -> dict[str, Any]:
    """Offset, delay and estimate-error statistics of one client/peer pair (s)."""
    out: dict[str, Any] = {
        "client": pair.client,
        "peer": pair.peer,
        "exchanges_count": len(pair.t3),
        "rejected_count": pair.rejected,
    }
    if not len(pair.t3):
        return out
    delay_median = float(np.nanmedian(pair.delay))
    out |= {
        "offset_median_s": float(np.nanmedian(pair.offset)),
        "offset_std_s": float(np.nanstd(pair.offset)),
        "delay_median_s": delay_median,
        "delay_std_s": float(np.nanstd(pair.delay)),
        "delay_max_deviation_s": float(np.nanmax(np.abs(pair.delay - delay_median))),
        "emulated_delay_s": emulated_delay_s,
        "delay_median_minus_emulated_s": (
            None if emulated_delay_s is None else delay_median - emulated_delay_s
        ),
    }
    if pair.truth is not None:
        out["true_offset_median_s"] = float(np.median(pair.truth))
        late = (pair.t3 - pair.t3[0] >= sync_phase) & np.isfinite(pair.estimate)
        error = np.abs(pair.estimate[late] - pair.truth[late])
        out["estimate_error_samples_count"] = int(error.size)
        if error.size:
            out |= {
                "estimate_error_median_abs_s": float(np.median(error)),
                "estimate_error_p95_abs_s": float(np.percentile(error, 95)),
                "estimate_error_max_abs_s": float(error.max()),
                "offset_median_error_s": out["offset_median_s"] - out["true_offset_median_s"],
            }
    return out


def follow_summary(f: Follow) -> dict[str, Any]:
    """Separations (s) and lag (s) of one follower."""
    sent_t, sent_h = f.sent[0], np.unwrap(f.sent[1])

    def shift(series: tuple[Array, Array] | None) -> float | None:
        if series is None:
            return None
        return best_shift(series[0], np.unwrap(series[1]), sent_t, sent_h, f.window)

    lag = None
    if f.heading is not None:  # while running: before the start, headings are not commanded
        (t, h), (t_l, h_l) = f.heading, f.leader_heading
        mine, theirs = t >= f.start, t_l >= f.start
        lag = xcorr_lag(t[mine], np.unwrap(h[mine]), t_l[theirs], np.unwrap(h_l[theirs]))
    return {
        "follower": f.follower,
        "leader": f.leader,
        "latency_compensation": f.compensation,
        "reference_separation_s": shift(f.reference),
        "received_separation_s": shift(f.received),
        "received_time_source": f.received_time,
        "pose_age_median_s": float(np.median(f.pose_age)) if f.pose_age.size else None,
        "lag_s": lag,
        "maneuver_s": None if f.window is None else [f.window[0] - f.start, f.window[1] - f.start],
        "pose_received_count": f.pose_received,
        **_error_vs_leader(f),
    }


def _error_vs_leader(f: Follow) -> dict[str, float | None]:
    """RMS and largest |heading error| against the leader's actual heading (deg)."""
    error = heading_error(f)
    if error is None:
        return {"heading_error_vs_leader_rms_deg": None, "heading_error_vs_leader_max_deg": None}
    e = np.degrees(error[1])
    return {
        "heading_error_vs_leader_rms_deg": float(np.sqrt(np.mean(e**2))),
        "heading_error_vs_leader_max_deg": float(np.max(np.abs(e))),
    }


def run_description(run: Run) -> dict[str, Any]:
    """The run as its recordings describe themselves (MCAP metadata ``fedlab.run``):
    run id, experiment, versions, date, each agent's command line; and whether the run
    was cut short (its run time never reached its duration)."""
    described: dict[str, dict[str, str]] = {}
    for name, rec in run.agents.items():
        meta = rec.metadata.get("fedlab.run")  # its first segment's
        if meta:
            described[name] = dict(meta)
    for name, meta in described.items():  # roles as the agents recorded them
        rec = run.agents[name]
        if rec.latency_compensation is None and meta.get("latency_compensation") in (
            "true",
            "false",
        ):
            rec.latency_compensation = meta["latency_compensation"] == "true"
    first = next(iter(described.values()), {})
    duration = _float(first.get("duration"))
    if duration is None and isinstance((run.meta or {}).get("duration_s"), int | float):
        duration = float((run.meta or {})["duration_s"])  # the demo's run.json
    ran = [
        m["run_time"]
        for rec in run.agents.values()
        for m in rec.channel(Channel.REFERENCE)
        if m.get("mode") in ("running", "done") and m.get("run_time") is not None
    ]
    reached = max(ran) if ran else None
    truncated = None
    if duration is not None and reached is not None:
        truncated = reached < duration - 0.5
    parts = participants(run)
    # A run the recordings do not describe (the demo's, recorded to one file per agent)
    # is described by its run.json.
    meta = run.meta or {}
    listed = meta.get("versions")
    versions: dict[str, Any] = listed if isinstance(listed, dict) else {}
    return {
        "run_id": first.get("run_id") or meta.get("run_id"),
        "experiment": _experiment_name(first.get("experiment", "")) or meta.get("experiment"),
        "utc_start": first.get("utc_start") or meta.get("utc_start"),
        "versions": {
            k: first.get(k) or versions.get(k)
            for k in ("fedlab_version", "zenoh_version", "python_version", "git_commit")
        },
        "run_duration_s": duration,
        "run_time_reached_s": reached,
        "truncated": truncated,
        # Per participant: the run time it reached, whether its run ended done.
        "participants": parts,
        "complete": bool(parts) and all(p["complete"] for p in parts.values()),
        "command_lines": {a: m.get("command_line") for a, m in described.items()},
        "hosts": {a: m.get("host") for a, m in described.items()},
        "clock_settings": {a: _clock_settings(m.get("agent_config")) for a, m in described.items()},
    }


def _clock_settings(config_json: str | None) -> dict[str, float | None]:
    """The skew an agent's settings added to its clock (``clock_offset`` s,
    ``clock_drift_ppm``), from the settings its recording holds; None where unknown."""
    import json

    try:
        config = json.loads(config_json or "")
    except ValueError:
        config = None
    if not isinstance(config, dict):
        config = {}
    return {
        k: float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None
        for k in ("clock_offset", "clock_drift_ppm")
        for v in [config.get(k)]
    }


def _float(text: str | None) -> float | None:
    try:
        return None if text in (None, "", "null") else float(text)
    except ValueError:
        return None


def _experiment_name(toml_text: str) -> str | None:
    for line in toml_text.splitlines():
        key, sep, value = line.partition("=")
        if sep and key.strip() == "name":
            return value.split("#", 1)[0].strip().strip('"')
    return None


def source_of(run: Run) -> dict[str, Any]:
    """The files a report was made from: ``merged`` (one merged file) or ``recordings``
    (one per agent and segment), by name, in the run folder."""
    return {"kind": "merged" if run.from_merged else "recordings", "files": list(run.sources)}


def summarize(run: Run, sync_phase: float = paper.SYNC_PHASE) -> dict[str, Any]:
    """Everything ``summary.json`` holds; seconds, degrees and counts named in the keys."""
    run = dataclasses.replace(run, notes=list(run.notes))  # notes: the caller's stay
    described = run_description(run)
    pairs = sync_pairs(run)
    follow_list = follows(run)
    followers = [follow_summary(f) for f in follow_list]
    for f in followers:
        for key, what in (
            ("reference_separation_s", f"separation within ±{SHIFT_MAX_S} s"),
            ("received_separation_s", f"received heading's separation within ±{SHIFT_MAX_S} s"),
            ("lag_s", "lag (no motion, or beyond the search range)"),
        ):
            if f[key] is None:
                run.notes.append(f"{f['follower']}: no {what}")
    agents: dict[str, Any] = {}
    for name, rec in run.agents.items():
        heading, source = heading_source(rec)
        rms = heading_rms_deg(heading, rec.channel(Channel.REFERENCE))
        if rms is None:
            run.notes.append(f"{name}: no heading and running reference to compare")
        agents[name] = {
            "recording": rec.file,
            "role": rec.role,
            "platform": rec.platform,
            "follow": rec.follow,
            "latency_compensation": rec.latency_compensation,
            "heading_rms_error_deg": rms,
            "heading_source": source,
            "pose_received_count": len(rec.channel(Channel.POSE_RECEIVED)),
            "messages_count": {k: len(v) for k, v in rec.messages.items() if v},
        }
    for pair in pairs:
        if pair.truth is None:
            run.notes.append(
                f"{pair.client} -> {pair.peer}: no clock truth (needs both agents' recordings)"
            )
    if not pairs:
        run.notes.append(f"no {Channel.SYNC_EXCHANGE} recorded by any agent")
    meta = run.meta or {}
    run.notes += incomplete_notes(described["participants"])
    if described["truncated"]:
        run.notes.append(
            f"truncated run: run time reached {described['run_time_reached_s']:.1f} s of "
            f"{described['run_duration_s']:g} s"
        )
    return {
        "run_dir": run.directory,
        "run": described,
        "leader": run.leader,
        "duration_s": meta.get("duration_s"),
        "command": meta.get("command"),
        "link": {
            "emulated_delay_s": run.emulated_delay_s,
            "emulated_jitter_s": run.emulated_jitter_s,
        },
        "sync_phase_s": sync_phase,
        "agents": agents,
        "sync": [sync_summary(p, run.emulated_delay_s, sync_phase) for p in pairs],
        "followers": followers,
        "paper": {f"{k}_range": list(v) for k, v in PAPER.items()},
        "notes": list(dict.fromkeys(run.notes)),
    }


# -- the table beside the paper ------------------------------------------------------------
def fmt(value: float | None, scale: float = 1.0, digits: int = 1) -> str:
    """``value * scale`` with ``digits`` decimals; "n/a" for None."""
    return "n/a" if value is None else f"{value * scale:.{digits}f}"


def _paper_range(key: str) -> str:
    """A range of :data:`PAPER` as printed: ``low–high`` (one number if they agree)."""
    lo, hi = PAPER[key]
    return f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}"


def compensation_label(value: bool | None) -> str:
    """How a follower's latency compensation is named in tables and legends."""
    return {True: "compensated", False: "raw", None: "compensation unknown"}[value]


def comparison_rows(summary: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(figure, pair or agent, this run, the paper) for the report and the terminal."""
    sync = [(f"{s['client']} → {s['peer']}", s) for s in summary["sync"]]
    followers = [
        (f"{f['follower']} ({compensation_label(f['latency_compensation'])})", f)
        for f in summary["followers"]
    ]
    agents = list(summary["agents"].items())
    emulated = [(w, s) for w, s in sync if s.get("emulated_delay_s") is not None]
    rows: list[tuple[str, str, str, str]] = []

    def add(
        label: str,
        entries: list[tuple[str, dict[str, Any]]],
        key: str,
        scale: float,
        digits: int,
        theirs: str,
    ) -> None:
        rows.extend((label, who, fmt(e.get(key), scale, digits), theirs) for who, e in entries)

    # Any offset is right: each clock starts at an arbitrary origin. The paper's is the
    # gap between its two labs' clocks, given for scale, not as a target.
    add(
        "offset median (s; any value: arbitrary clock origins)",
        sync,
        "offset_median_s",
        1,
        4,
        f"{paper.CLOCK_OFFSET:.3f} (its labs' clocks)",
    )
    add("offset std (ms)", sync, "offset_std_s", 1e3, 2, _paper_range("offset_std_ms"))
    errors = ("estimate_error_median_abs_s", "estimate_error_p95_abs_s", "estimate_error_max_abs_s")
    rows.extend(
        (
            "estimate |error| vs truth, p50/p95/max (ms)",
            who,
            "/".join(fmt(s.get(k), 1e3, 3) for k in errors),
            "no truth",
        )
        for who, s in sync
    )
    add("delay median (ms)", sync, "delay_median_s", 1e3, 2, _paper_range("delay_median_ms"))
    add("delay median − emulated (ms)", emulated, "delay_median_minus_emulated_s", 1e3, 2, "n/a")
    add("delay std (ms)", sync, "delay_std_s", 1e3, 2, _paper_range("delay_std_ms"))
    separation = _paper_range("separation_ms")
    label = "received-vs-sent separation, {} (ms)"
    add(label.format("received heading"), followers, "received_separation_s", 1e3, 1, separation)
    add(
        label.format("follower's reference"),
        followers,
        "reference_separation_s",
        1e3,
        1,
        separation,
    )
    add("follower lag (s)", followers, "lag_s", 1, 2, _paper_range("lag_s"))
    add("heading RMS error (deg)", agents, "heading_rms_error_deg", 1, 3, "n/a")
    return rows


def summary_table(summary: dict[str, Any], title: str = "this run beside the paper") -> Any:
    """The comparison rows as a :class:`rich.table.Table`, for the terminal."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("figure")
    table.add_column("pair or agent")
    table.add_column("this run", justify="right")
    table.add_column("paper", justify="right")
    for row in comparison_rows(summary):
        table.add_row(*row)
    return table

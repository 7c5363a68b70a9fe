"""Runs of a framed scenario (formation, docking, a plug-in's): their figures in
``summary.json`` and their plots.

The experiment comes from the run's ``run.json`` (``experiment``, as the demo writes
it) or ``experiment.json`` beside the recordings. Every simulated agent records its
true pose (``/truth``) in the common frame (:class:`agents.workspace.FramedPlatform`);
agents on one host share ``host_monotonic``, so their truths line up exactly, and the
leader's ``/reference`` messages give run time.

Keys added to the summary:

- ``formation``: ``error_rms_m``, ``error_max_m`` (every platform's distance from its
  slot around the path's centre, truth, every 0.1 s of run time), per platform, the
  latency compensation and the emulated delay;
- ``docking``: ``success``, ``contact_speed_mps``, ``lateral_error_m``,
  ``heading_error_deg``, ``time_s`` (run time of the first contact on the truth),
  the chaser's phases;
- ``workspace``: per platform, ``violations`` (times its true centre left the usable
  area), ``clamped`` and ``holds`` (its counters), for every framed scenario.

A scenario's own figures are found by its name in :data:`SCENARIO_FIGURES`; a framed
scenario without an entry there gets its workspace and trajectories only.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from agents.docking import contact_state
from agents.formation import CirclePath, slot_errors
from agents.registry import scenario_class
from agents.workspace import Area, Frame
from federation.core.channels import Channel
from federation.core.wire import Pose
from federation.report.load import Run
from schemas.base import ConfigError, validate
from schemas.experiment import ExperimentConfig
from schemas.platform import load_platform
from schemas.scenario import LabFrame

__all__ = [
    "SCENARIO_FIGURES",
    "experiment_of",
    "markdown_section",
    "scenario_summary",
    "write_scenario_figures",
]

Array = np.ndarray[Any, np.dtype[np.float64]]
GRID_S = 0.1  # s between formation samples
CONTACT_GRID_S = 0.01  # s between docking samples


# Rules for launching a run, not for what a run flew: a run recorded before one was
# made stricter is read with its value raised to today's least, so its report loads.
_LAUNCH_ONLY_LEAST = {"start_delay": 1.0}


def experiment_of(run: Run) -> ExperimentConfig | None:
    """The run's experiment (run.json's ``experiment``, else experiment.json), if any.

    ConfigError naming the file and the field when it does not load."""
    data = (run.meta or {}).get("experiment")
    source = "run.json: experiment"
    if not isinstance(data, dict) and run.experiment_json is not None:
        source = f"{', '.join(run.sources)}: experiment.json"  # the merged file's copy
        try:
            data = json.loads(run.experiment_json)
        except ValueError as error:
            raise ConfigError(f"{source}: not JSON: {error}") from None
    elif not isinstance(data, dict) and run.directory:
        path = Path(run.directory) / "experiment.json"
        if path.is_file():
            source = str(path)
            try:
                data = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as error:  # cut short, not UTF-8, unreadable
                raise ConfigError(f"{source}: not a JSON file: {error}") from None
    if not isinstance(data, dict):
        return None
    data = dict(data)
    for field, least in _LAUNCH_ONLY_LEAST.items():
        value = data.get(field)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value < least:
            data[field] = least
    return validate(ExperimentConfig, data, source)


def _experiment_or_note(run: Run) -> tuple[ExperimentConfig | None, str | None]:
    """The run's experiment, or why it cannot be read (the rest of the report stands)."""
    try:
        return experiment_of(run), None
    except ConfigError as error:
        return None, f"the run's experiment does not load ({error}): no scenario figures"


def _truth(run: Run, agent: str) -> dict[str, Array] | None:
    rec = run.agents.get(agent)
    rows = [] if rec is None else rec.channel(Channel.TRUTH)
    if not rows:
        return None
    return {k: np.array([r[k] for r in rows], dtype=float) for k in rows[0] if k != "t_exec"}


def _run_time_origin(run: Run, experiment: ExperimentConfig) -> float | None:
    """host_monotonic at run time 0, from the leader's reference messages."""
    rec = run.agents.get(str(experiment.leader))
    rows = [] if rec is None else rec.channel(Channel.REFERENCE)
    origins = [r["host_monotonic"] - r["run_time"] for r in rows if r.get("run_time") is not None]
    return float(np.median(origins)) if origins else None


def _at(truth: dict[str, Array], host: Array) -> dict[str, Array]:
    t = truth["host_monotonic"]
    return {k: np.interp(host, t, v) for k, v in truth.items() if k != "host_monotonic"}


def _frames(experiment: ExperimentConfig) -> dict[str, tuple[Frame, Area | None]]:
    out = {}
    for p in experiment.participants:
        lab = p.agent.split("/")[0]
        frame = Frame.from_config(experiment.frames.get(lab, LabFrame()))
        try:
            area: Area | None = Area.of(load_platform(p.platform))
        except ValueError:  # kinematic or serial: no physical description here
            area = None
        out[p.agent] = (frame, area)
    return out


def _framed(experiment: ExperimentConfig | None) -> bool:
    """Whether the experiment's scenario flies in the common frame, each platform kept in
    its area: its truths, areas and trajectories make figures (attitude tracking's don't)."""
    return experiment is not None and scenario_class(experiment.kind).framed


def scenario_summary(run: Run) -> dict[str, Any]:
    """``workspace`` figures of a framed scenario and its own (``formation``,
    ``docking``: :data:`SCENARIO_FIGURES`); empty for attitude tracking."""
    experiment, why = _experiment_or_note(run)
    if why is not None:
        return {"notes": [why]}
    if experiment is None or not _framed(experiment):
        return {}
    origin = _run_time_origin(run, experiment)
    truths = {p.agent: _truth(run, p.agent) for p in experiment.participants}
    out: dict[str, Any] = {"scenario": experiment.kind}
    out["workspace"] = _workspace(run, experiment, truths)
    own = SCENARIO_FIGURES.get(experiment.kind)
    if own is None:  # a scenario with no figures of its own: its workspace only
        return out
    if origin is None or any(v is None for v in truths.values()):
        out["notes"] = ["no run time or no truth for every platform: no scenario figures"]
        return out
    present = {a: v for a, v in truths.items() if v is not None}
    start = max(v["host_monotonic"][0] for v in present.values())
    end = min(v["host_monotonic"][-1] for v in present.values())
    start = max(start, origin)
    if end <= start:
        out["notes"] = ["the platforms' truths do not overlap after the start"]
        return out
    link = (run.meta or {}).get("link") or {}
    grid, figures_of = own
    host = np.arange(start, end, grid)
    at = {a: _at(v, host) for a, v in present.items()}
    figures = figures_of(run, experiment, at, host, origin)
    figures["delay_ms"] = link.get("delay_ms")
    out[experiment.kind] = figures
    return out


def _formation(
    run: Run,
    experiment: ExperimentConfig,
    at: dict[str, dict[str, Array]],
    host: Array,
    origin: float,
) -> dict[str, Any]:
    """Formation figures from the truths ``at`` the host times ``host``."""
    f = experiment.formation
    assert f is not None
    names = list(at)
    errors = np.zeros((len(host), len(names)))
    for k, h in enumerate(host):
        poses = {a: Pose(float(at[a]["x"][k]), float(at[a]["y"][k])) for a in names}
        e = slot_errors(f, float(h - origin), poses)
        errors[k] = [e[a] for a in names]
    compensation = {p.latency_compensation for p in experiment.participants}
    return {
        "error_rms_m": float(np.sqrt(np.mean(errors**2))),
        "error_max_m": float(np.max(errors)),
        "latency_compensation": compensation.pop() if len(compensation) == 1 else None,
        "samples": len(host),
        "per_platform": {
            a: {
                "error_rms_m": float(np.sqrt(np.mean(errors[:, i] ** 2))),
                "error_max_m": float(np.max(errors[:, i])),
            }
            for i, a in enumerate(names)
        },
        "series": {
            "run_time_s": (host - origin).round(3).tolist(),
            "error_m": {a: errors[:, i].round(5).tolist() for i, a in enumerate(names)},
        },
    }


def _docking(
    run: Run,
    experiment: ExperimentConfig,
    at: dict[str, dict[str, Array]],
    host: Array,
    origin: float,
) -> dict[str, Any]:
    """Docking figures from the truths ``at`` the host times ``host``."""
    d = experiment.docking
    assert d is not None
    c, t = at[d.chaser], at[d.target]
    keys = ("x", "y", "heading", "vx", "vy", "omega")
    contact = None
    ranges = []
    for k in range(len(host)):
        state = contact_state(
            Pose(*(float(c[n][k]) for n in keys)), Pose(*(float(t[n][k]) for n in keys))
        )
        ranges.append(math.hypot(state.axial, state.lateral))
        if contact is None and state.axial <= d.contact_distance:
            contact = (float(host[k] - origin), state)
    rec = run.agents.get(d.chaser)
    phases: list[tuple[float, str]] = []
    for r in [] if rec is None else rec.channel(Channel.REFERENCE):
        phase = r.get("phase")
        if phase and r.get("run_time") is not None and (not phases or phases[-1][1] != phase):
            phases.append((round(float(r["run_time"]), 2), str(phase)))
    out: dict[str, Any] = {
        "success": False,
        "contact_speed_mps": None,
        "lateral_error_m": None,
        "heading_error_deg": None,
        "time_s": None,
        "criteria": d.contact.model_dump(),
        "phases": phases,
        "series": {
            "run_time_s": (host[::10] - origin).round(3).tolist(),
            "range_m": np.array(ranges[::10]).round(4).tolist(),
        },
    }
    if contact is not None:
        time_s, s = contact
        heading_deg = math.degrees(abs(s.heading_error))
        out |= {
            "contact_speed_mps": s.closing_speed,
            "lateral_error_m": abs(s.lateral),
            "heading_error_deg": heading_deg,
            "time_s": time_s,
            "success": s.closing_speed <= d.contact.max_speed
            and abs(s.lateral) <= d.contact.max_lateral
            and heading_deg <= d.contact.max_heading_deg,
        }
    return out


Figures = Callable[
    [Run, ExperimentConfig, dict[str, dict[str, Array]], Array, float], dict[str, Any]
]
"""A scenario's figures from the run, its experiment, the truths at the host times of
its grid, those times and host_monotonic at run time 0."""

SCENARIO_FIGURES: dict[str, tuple[float, Figures]] = {
    "formation": (GRID_S, _formation),
    "docking": (CONTACT_GRID_S, _docking),
}
"""Scenario -> (s between samples, its figures): the summary's key is the scenario's name."""


def _workspace(
    run: Run, experiment: ExperimentConfig, truths: dict[str, dict[str, Array] | None]
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for agent, (frame, area) in _frames(experiment).items():
        truth = truths.get(agent)
        violations = None
        if truth is not None and area is not None:
            inside_before = True
            violations = 0
            for x, y in zip(truth["x"], truth["y"], strict=True):
                tx, ty = frame.point_to_table(float(x), float(y))
                inside = area.contains(tx, ty)
                if inside_before and not inside:
                    violations += 1
                inside_before = inside
        rec = run.agents.get(agent)
        status = [] if rec is None else rec.channel(Channel.STATUS)
        counters = status[-1].get("counters", {}) if status else {}
        out[agent] = {
            "violations": violations,
            "clamped": counters.get("workspace_clamped"),
            "holds": counters.get("workspace_holds"),
        }
    return out


# -- figures -----------------------------------------------------------------------------
def write_scenario_figures(run: Run, summary: dict[str, Any], out: Path) -> dict[str, Path]:
    """``trajectories.png`` (common frame and each table), ``formation_error.png`` or
    ``relative_range.png``."""
    experiment, _ = _experiment_or_note(run)  # why not: in the summary's notes
    if experiment is None or not _framed(experiment):
        return {}
    import matplotlib

    matplotlib.use("Agg")
    figures = {"trajectories": _trajectories_figure(run, experiment, out / "trajectories.png")}
    formation = summary.get("formation")
    if formation is not None:
        figures["formation_error"] = _formation_figure(formation, out / "formation_error.png")
    docking = summary.get("docking")
    if docking is not None:
        assert experiment.docking is not None
        figures["relative_range"] = _docking_figure(
            docking, experiment.docking.contact_distance, out / "relative_range.png"
        )
    return figures


def _save(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _trajectories_figure(run: Run, experiment: ExperimentConfig, path: Path) -> Path:
    """Every platform's true track in the common frame (with the formation's virtual
    centre) and, beside it, each in its own table's frame."""
    import matplotlib.pyplot as plt

    frames = _frames(experiment)
    n = len(frames)
    fig, axes = plt.subplots(1, n + 1, figsize=(5 * (n + 1), 5))
    common = axes[0]
    for i, (agent, (frame, area)) in enumerate(frames.items()):
        _plot_table(common, axes[i + 1], agent, frame, area, _truth(run, agent), f"C{i}")
    if experiment.formation is not None:
        centre = CirclePath(experiment.formation)
        ts = np.linspace(0, experiment.duration, 400)
        pts = [centre(float(t)) for t in ts]
        common.plot([p.x for p in pts], [p.y for p in pts], "k:", label="virtual centre")
    common.set_title("common frame (dashed: usable areas)")
    common.set_xlabel("x (m)")
    common.set_ylabel("y (m)")
    common.set_aspect("equal", adjustable="datalim")
    common.autoscale_view()
    common.legend(loc="best", fontsize=8)
    return _save(fig, path)


def _plot_table(
    common: Any,
    ax: Any,
    agent: str,
    frame: Frame,
    area: Area | None,
    truth: dict[str, Array] | None,
    color: str,
) -> None:
    """``agent``'s truth and usable area on the common axes and on its own table's."""
    from matplotlib.patches import Polygon

    if area is not None:
        corners = frame.area_to_common(area)
        common.add_patch(Polygon(corners, fill=False, ls="--", color=color))
    if truth is not None:
        common.plot(truth["x"], truth["y"], color=color, label=agent)
        table = [
            frame.point_to_table(float(x), float(y))
            for x, y in zip(truth["x"], truth["y"], strict=True)
        ]
        ax.plot([p[0] for p in table], [p[1] for p in table], color=color)
    if area is not None:
        ax.add_patch(
            Polygon(
                [(area.x_min, area.y_min), (area.x_max, area.y_min),
                 (area.x_max, area.y_max), (area.x_min, area.y_max)],
                fill=False, ls="--", color="k", label="usable area",
            )
        )  # fmt: skip
    ax.set_title(f"{agent}: own table frame")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize=8)


def _formation_figure(formation: dict[str, Any], path: Path) -> Path:
    """Each platform's distance from its slot over run time."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    s = formation["series"]
    for agent, e in s["error_m"].items():
        ax.plot(s["run_time_s"], np.array(e) * 100, label=agent)
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("distance from slot (cm)")
    label = "compensated" if formation.get("latency_compensation") else "not compensated"
    ax.set_title(
        f"formation error, {formation.get('delay_ms')} ms one way, {label}: "
        f"RMS {formation['error_rms_m'] * 100:.2f} cm"
    )
    ax.legend()
    return _save(fig, path)


def _docking_figure(docking: dict[str, Any], contact_distance: float, path: Path) -> Path:
    """The chaser's true range to the target over run time, with its phases."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    s = docking["series"]
    ax.plot(s["run_time_s"], s["range_m"], label="chaser to target, truth")
    ax.axhline(contact_distance, color="k", ls="--", label="contact")
    for t, phase in docking["phases"]:
        ax.axvline(t, color="grey", lw=0.5)
        ax.text(t, ax.get_ylim()[1], phase, rotation=90, va="top", fontsize=8)
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("relative range (m)")
    ax.set_title(f"docking: {'success' if docking['success'] else 'no success'}")
    ax.legend()
    return _save(fig, path)


def markdown_section(summary: dict[str, Any]) -> str:
    """The report's scenario section (empty for attitude tracking)."""
    lines: list[str] = []
    f, d = summary.get("formation"), summary.get("docking")
    if f is not None:
        comp = "with" if f.get("latency_compensation") else "without"
        lines += [
            "## Formation",
            "",
            f"{f.get('delay_ms')} ms one way, {comp} latency compensation: formation error "
            f"RMS **{f['error_rms_m'] * 100:.2f} cm**, max {f['error_max_m'] * 100:.2f} cm "
            f"({f['samples']} samples every {GRID_S} s, truth).",
            "",
            "![formation error](formation_error.png)",
            "",
        ]
    if d is not None:
        lines += ["## Docking", ""]
        if d["time_s"] is None:
            lines.append("No contact.")
        else:
            lines.append(
                f"{'Success' if d['success'] else 'No success'} at run time {d['time_s']:.1f} s: "
                f"closing speed {d['contact_speed_mps'] * 100:.2f} cm/s, lateral "
                f"{d['lateral_error_m'] * 100:.2f} cm, heading {d['heading_error_deg']:.2f} deg."
            )
        lines += ["", "![relative range](relative_range.png)", ""]
    ws = summary.get("workspace")
    if ws:
        lines += [
            "## Workspace",
            "",
            "| platform | violations | clamped | holds |",
            "|---|---:|---:|---:|",
        ]
        for agent, w in ws.items():
            lines.append(f"| {agent} | {w['violations']} | {w['clamped']} | {w['holds']} |")
        lines += ["", "![trajectories](trajectories.png)", ""]
    return "\n".join(lines)

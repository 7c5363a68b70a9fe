"""``fedlab demo``: the paper's experiment, end to end, on this machine.

Two lab routers as separate processes (``kiruna`` listens, ``rome`` dials it
through the link emulator, which gives the lab link the paper's ~40 ms one-way
delay), a simulated KNATTE leading in ``kiruna`` and a simulated PINOCCHIO
following in ``rome`` with its clock 26.42 s off. A second PINOCCHIO
(``rome/pinocchio-raw``) follows without latency compensation, so the report
shows both. Once the followers are synchronized the demo starts the run the way
``fedlab ctl start`` does (a common reference instant), shows progress, stops
everything (also on Ctrl-C), writes the report and sets this run beside the
paper's numbers.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from federation.core import paper
from federation.core.channels import recording_stem
from federation.fleet.launch import Fleet, free_port, wait_for
from federation.fleet.progress import DemoProgress, run_line
from federation.report.status import last_status
from federation.report.summary import PAPER
from federation.runtime.monitor import CLOCKS_NOTE

PAPER_MANEUVER = {
    "still": paper.MANEUVER_STILL,
    "duration": paper.MANEUVER_DURATION,
    "amplitude_deg": paper.MANEUVER_AMPLITUDE_DEG,
}
"""The hardware run's maneuver (docs/paper.md)."""

__all__ = ["SCENARIOS", "run_demo", "run_scenario_demo"]

LEADER, FOLLOWER, RAW = "kiruna/knatte", "rome/pinocchio", "rome/pinocchio-raw"
START_IN = 2.0  # s between the start command and the common start instant


def experiment(duration: float) -> dict[str, Any]:
    return {
        "name": "attitude-tracking-demo",
        "duration": duration,
        "start_delay": START_IN,
        "maneuver": PAPER_MANEUVER,
        "participants": [
            {"agent": LEADER, "role": "leader", "platform": "knatte"},
            {"agent": FOLLOWER, "role": "follower", "platform": "pinocchio", "follow": LEADER},
            {"agent": RAW, "role": "follower", "platform": "pinocchio", "follow": LEADER,
             "latency_compensation": False},
        ],
    }  # fmt: skip


def _progress(run: Path, elapsed: float, total: float, phase: str) -> Table:
    title = "fedlab demo: " + (run_line(elapsed, total) if phase == "running" else phase)
    table = Table(title=title, caption=CLOCKS_NOTE, caption_justify="left")
    for column in ("agent", "mode", "run time (s)", "heading (deg)", "offset (s)", "delay (ms)"):
        table.add_column(column, justify="right")
    for agent in (LEADER, FOLLOWER, RAW):
        line = last_status(run / f"{recording_stem(agent)}.jsonl")
        if line is None:
            table.add_row(agent, "starting", "", "", "", "")
            continue
        peer = line["peers"].get(LEADER) if agent != LEADER else None
        offset = None if peer is None else peer["offset"]
        delay = None if peer is None else peer["delay"]
        table.add_row(
            agent,
            line.get("mode", "?"),
            "-" if line.get("run_time") is None else f"{line['run_time']:.1f}",
            f"{math.degrees(line['pose'][2]):6.2f}",
            "ref" if agent == LEADER else "-" if offset is None else f"{offset:+.4f}",
            "-" if delay is None else f"{delay * 1e3:.2f}",
        )
    return table


def _start_run(
    endpoint: str,
    seconds_ahead: float,
    experiment: str = "attitude-tracking-demo",
    run_id: str | None = None,
) -> float:
    """Announce the start of run ``run_id`` as ``fedlab ctl start`` does; returns the
    reference start time."""
    import zenoh

    from federation.core import keys
    from federation.core.keys import AgentId
    from federation.runtime.clock import ExecClock
    from federation.runtime.refclock import reference_now
    from federation.runtime.session import build_config
    from schemas.config import ManeuverConfig, ZenohOptions
    from schemas.messages import Command

    conf = build_config(ZenohOptions(connect=[endpoint]), default_mode="client")
    with zenoh.open(conf) as session:
        clock = ExecClock()
        at = reference_now(session, "default", AgentId.parse(LEADER), clock) + seconds_ahead
        command = Command(
            command="start", at=at, seq=time.time_ns() // 1_000_000, issuer="demo",
            experiment=experiment, run_id=run_id,
            maneuver=ManeuverConfig(**PAPER_MANEUVER),
        )  # fmt: skip
        for _ in range(3):
            session.put(keys.control_key("default"), command.model_dump_json())
            time.sleep(0.05)
    return at


def _unshown(table: Table) -> None:
    """Where no live display is drawn (not a terminal): the progress lines say it."""


def run_identity(experiment: str, seconds_ahead: float = START_IN) -> dict[str, Any]:
    """What names a demo run in its run.json (and so in summary.json and the report):
    its run id (``<experiment>-<UTC time>``, as ``fedlab ctl start`` makes it), its
    experiment, its UTC start (``seconds_ahead`` from now) and the software's versions."""
    import datetime

    from federation.runtime.control import make_run_id
    from federation.runtime.runs import software_versions

    start = datetime.datetime.now(datetime.UTC) + datetime.timedelta(seconds=seconds_ahead)
    return {
        "run_id": make_run_id(experiment, start),
        "experiment": experiment,
        "utc_start": start.isoformat(timespec="seconds"),
        "versions": software_versions(),
    }


def run_demo(
    duration: float,
    out: Path,
    delay_ms: float = paper.ONE_WAY_DELAY * 1e3,
    clock_offset: float = paper.CLOCK_OFFSET,
) -> int:
    """Run the demo; ``duration`` is seconds of run time after the common start."""
    console = Console()
    progress = DemoProgress(console)
    out.mkdir(parents=True, exist_ok=True)
    for old in [*out.glob("*.mcap"), *out.glob("*.jsonl"), *out.glob("*.png")]:
        old.unlink()
    spec = experiment(duration)
    (out / "experiment.json").write_text(json.dumps(spec, indent=1) + "\n")
    kiruna, link, rome = (f"tcp/127.0.0.1:{free_port()}" for _ in range(3))
    jitter_ms = 2.0
    agents = {
        LEADER: {"endpoint": kiruna, "clock_offset": 0.0},
        FOLLOWER: {"endpoint": rome, "clock_offset": clock_offset},
        RAW: {"endpoint": rome, "clock_offset": clock_offset + 3.1},
    }
    started = time.monotonic()
    interrupted = False
    identity: dict[str, Any] = {}
    with Fleet(out / "logs") as fleet:
        progress.phase("starting routers and the lab link")
        fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
        fleet.start(
            "link",
            ["link", "--listen", link, "--to", kiruna, "--delay-ms", f"{delay_ms}",
             "--jitter-ms", f"{jitter_ms}", "--seed", "1"],
        )  # fmt: skip
        fleet.start("router-rome", ["router", "--lab", "rome", "-l", rome, "-e", link])
        progress.phase(f"starting agents: {', '.join(agents)}")
        for agent, a in agents.items():
            lab, name = agent.split("/")
            fleet.start(
                recording_stem(agent),
                ["agent", "--experiment", str(out / "experiment.json"), "--lab", lab,
                 "--name", name, "-e", str(a["endpoint"]), "--clock-offset", f"{a['clock_offset']}",
                 "--status-json", str(out / f"{recording_stem(agent)}.jsonl"),
                 "--record", str(out / f"{recording_stem(agent)}.mcap"),
                 # Followers query the leader; the leader queries everyone (the paper's
                 # two channels).
                 *(["--sync-with", LEADER] if agent != LEADER else [])],
            )  # fmt: skip
        total = duration + START_IN
        progress.phase("synchronizing the followers' clocks with the leader's")
        try:
            # Redrawn in place on a terminal; elsewhere the progress lines say it.
            with Live(console=console, refresh_per_second=2, transient=not progress.live) as live:
                show: Callable[[Table], None] = live.update if progress.live else _unshown

                def synced() -> bool:
                    show(_progress(out, time.monotonic() - started, total, "syncing"))
                    lines = [
                        last_status(out / f"{recording_stem(a)}.jsonl") for a in (FOLLOWER, RAW)
                    ]
                    return all(line is not None and line["t_sim"] is not None for line in lines)

                if not wait_for(synced, timeout=30, interval=0.1):
                    console.print(
                        f"[red]the followers never synchronized; see {out / 'logs'}[/red]"
                    )
                    return 1
                identity = run_identity(str(spec["name"]))
                progress.phase(f"running {identity['run_id']}: {total:.0f} s")
                _start_run(kiruna, START_IN, str(spec["name"]), identity["run_id"])
                t0 = time.monotonic()
                while (elapsed := time.monotonic() - t0) < total:
                    show(_progress(out, elapsed, total, "running"))
                    progress.run(elapsed, total, shown_live=progress.live)
                    if not all(fleet.alive(recording_stem(a)) for a in agents):
                        console.print(f"[red]an agent stopped early; see {out / 'logs'}[/red]")
                        break
                    time.sleep(min(0.5, total - elapsed))  # ends when the run does
        except KeyboardInterrupt:
            interrupted = True
            console.print("interrupted: stopping agents, link and routers")
        progress.phase("stopping agents (each closes its recording), the link and the routers")
        codes = fleet.stop_all()
    run = {
        **identity,
        "leader": LEADER,
        "agents": {
            p["agent"]: {
                "role": p["role"],
                "platform": p["platform"],
                "follow": p.get("follow"),
                "latency_compensation": p.get("latency_compensation", True),
                "clock_offset": agents[p["agent"]]["clock_offset"],
                "clock_drift_ppm": 0.0,
            }
            for p in spec["participants"]
        },
        "link": {"delay_ms": delay_ms, "jitter_ms": jitter_ms, "jitter_dist": "normal"},
        "duration_s": duration,
        "exit_codes": codes,
        "command": " ".join(["fedlab", *sys.argv[1:]]) if sys.argv else "fedlab demo",
    }
    (out / "run.json").write_text(json.dumps(run, indent=1) + "\n")
    summary = _merge_and_report(out, progress, console)
    console.print(paper_table(summary))
    console.print(_written(out, summary), highlight=False)
    if interrupted:
        return 130
    return 0


def _written(out: Path, summary: dict[str, Any]) -> str:
    """What the demo left in ``out``, the merged file named when the report read it."""
    if (summary.get("source") or {}).get("kind") == "merged":
        return (
            f"report.md, summary.json, figures, recordings and the merged run in {out} "
            "(merged.mcap: open it in Foxglove with its layout merged.layout.json)"
        )
    return f"report.md, summary.json, figures and recordings in {out}"


def _merge_and_report(out: Path, progress: DemoProgress, console: Console) -> dict[str, Any]:
    """Merge the run into ``out/merged.mcap`` (for Foxglove, with its layout) and write
    the report from it; a merge that fails is printed, and the report reads the
    recordings."""
    from rich.text import Text

    from federation.report import write_report
    from federation.report.merge import merge_folder

    progress.phase("merging the recordings on reference time")
    merged = merge_folder(out)
    if "error" in merged:
        console.print(Text(f"merge failed: {merged['error']}; the report reads the recordings",
                           style="red"))  # fmt: skip
    progress.phase("writing the report")
    summary = write_report(out, out)
    if "error" not in merged:
        console.print(
            f"merged run for Foxglove: {merged['file']} (layout {merged['layout']})",
            highlight=False,
        )
    return summary


def _find(rows: list[dict[str, Any]], **match: str) -> dict[str, Any]:
    return next((r for r in rows if all(r.get(k) == v for k, v in match.items())), {})


def paper_table(summary: dict[str, Any]) -> Table:
    """This run beside the paper (docs/paper.md), for the compensated follower's view."""
    pair = _find(summary.get("sync", []), client=FOLLOWER, peer=LEADER)
    comp = _find(summary.get("followers", []), follower=FOLLOWER)
    raw = _find(summary.get("followers", []), follower=RAW)
    agents = summary.get("agents", {})

    def ms(value: Any, digits: int = 2) -> str:
        return "-" if value is None else f"{value * 1e3:.{digits}f}"

    def s(value: Any) -> str:
        return "-" if value is None else f"{value:.2f}"

    def deg(agent: str) -> str:
        value = agents.get(agent, {}).get("heading_rms_error_deg")
        return "-" if value is None else f"{value:.2f}"

    def paper_range(key: str) -> str:
        low, high = PAPER[key]
        return f"{low:g} to {high:g}"

    table = Table(title=f"{FOLLOWER} and {LEADER}: this run beside the paper")
    table.add_column("figure")
    table.add_column("this run", justify="right")
    table.add_column("paper (Kiruna-Rome, internet)", justify="right")
    rows = [
        ("offset error vs truth, median (ms)", ms(pair.get("estimate_error_median_abs_s"), 3),
         "unknown (no truth)"),
        ("offset error vs truth, p95 (ms)", ms(pair.get("estimate_error_p95_abs_s"), 3), ""),
        ("offset per exchange, std (ms)", ms(pair.get("offset_std_s")),
         paper_range("offset_std_ms")),
        ("one-way delay, median (ms)", ms(pair.get("delay_median_s")),
         paper_range("delay_median_ms")),
        ("  emulated (ms)", ms(pair.get("emulated_delay_s")), ""),
        ("one-way delay, std (ms)", ms(pair.get("delay_std_s")), paper_range("delay_std_ms")),
        ("received heading behind sent (ms)", ms(raw.get("received_separation_s"), 1),
         paper_range("separation_ms")),
        ("tracked reference behind sent, raw (ms)", ms(raw.get("reference_separation_s"), 1),
         ""),
        ("  with latency compensation (ms)", ms(comp.get("reference_separation_s"), 1), ""),
        ("follower lag (s), compensated / raw", f"{s(comp.get('lag_s'))} / {s(raw.get('lag_s'))}",
         paper_range("lag_s")),
        ("heading RMS error (deg): leader", deg(LEADER), ""),
        ("  follower, compensated / raw", f"{deg(FOLLOWER)} / {deg(RAW)}", ""),
    ]  # fmt: skip
    for row in rows:
        table.add_row(*row)
    return table


# -- scenarios beyond attitude ------------------------------------------------------------
SCENARIOS = ("attitude", "formation", "docking")
"""``fedlab demo --scenario``: attitude is the paper's experiment above."""

EXPERIMENTS_DIR = Path(__file__).resolve().parents[2] / "deploy" / "experiments"
SCENARIO_CLOCKS = {"kiruna": 0.0, "rome": paper.CLOCK_OFFSET, "lab3": -7.3}
"""Each lab's clock offset, s (kiruna's is the reference)."""


def scenario_experiment(
    scenario: str, duration: float | None, compensate: bool, seed: int
) -> dict[str, Any]:
    """deploy/experiments/<scenario>.toml as a dict, with the demo's settings."""
    import tomllib

    text = (EXPERIMENTS_DIR / f"{scenario}.toml").read_text(encoding="utf-8")
    spec = tomllib.loads(text)
    spec["name"] = f"{scenario}-demo"
    spec["start_delay"] = START_IN
    if duration is not None:
        spec["duration"] = duration
    for i, p in enumerate(spec["participants"]):
        p["latency_compensation"] = compensate
        p["seed"] = seed * 100 + i
    if "relative_sensor" in spec:
        spec["relative_sensor"]["seed"] = spec["relative_sensor"].get("seed", 0) + seed
    from schemas.base import validate
    from schemas.experiment import ExperimentConfig

    validate(ExperimentConfig, spec, str(EXPERIMENTS_DIR / f"{scenario}.toml"))
    return spec


def run_scenario_demo(
    scenario: str,
    out: Path,
    duration: float | None = None,
    delay_ms: float = paper.ONE_WAY_DELAY * 1e3,
    compensate: bool = True,
    seed: int = 0,
) -> int:
    """A formation or docking run on this machine: kiruna's router listens, every other
    lab's router dials it through its own link emulator (``delay_ms`` one way), one
    simulated platform per lab; then the report (formation error, docking outcome,
    workspace) in ``out``."""
    console = Console()
    progress = DemoProgress(console)
    out.mkdir(parents=True, exist_ok=True)
    for old in [*out.glob("*.mcap"), *out.glob("*.jsonl"), *out.glob("*.png")]:
        old.unlink()
    spec = scenario_experiment(scenario, duration, compensate, seed)
    run_s = float(spec["duration"])
    (out / "experiment.json").write_text(json.dumps(spec, indent=1) + "\n")
    agents = [p["agent"] for p in spec["participants"]]
    labs = sorted({a.split("/")[0] for a in agents}, key=lambda lab: lab != "kiruna")
    kiruna = f"tcp/127.0.0.1:{free_port()}"
    endpoints = {"kiruna": kiruna}
    jitter_ms = 2.0
    started = time.monotonic()
    interrupted = False
    identity: dict[str, Any] = {}
    with Fleet(out / "logs") as fleet:
        progress.phase(f"starting routers and lab links: {', '.join(labs)}")
        fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
        for i, lab in enumerate(labs[1:]):
            link, own = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
            fleet.start(
                f"link-{lab}",
                ["link", "--listen", link, "--to", kiruna, "--delay-ms", f"{delay_ms}",
                 "--jitter-ms", f"{jitter_ms}", "--seed", f"{seed * 10 + i + 1}"],
            )  # fmt: skip
            fleet.start(f"router-{lab}", ["router", "--lab", lab, "-l", own, "-e", link])
            endpoints[lab] = own
        progress.phase(f"starting agents: {', '.join(agents)}")
        for agent in agents:
            lab, name = agent.split("/")
            fleet.start(
                recording_stem(agent),
                ["agent", "--experiment", str(out / "experiment.json"), "--lab", lab,
                 "--name", name, "-e", endpoints[lab],
                 "--clock-offset", f"{SCENARIO_CLOCKS.get(lab, 1.5)}",
                 "--status-json", str(out / f"{recording_stem(agent)}.jsonl"),
                 "--record", str(out / f"{recording_stem(agent)}.mcap"),
                 # A sync reply takes a round trip: over a relay satellite's 250 ms one
                 # way, longer than the default 0.5 s timeout.
                 "--sync-timeout", f"{max(0.5, 4 * delay_ms / 1e3):g}"],
            )  # fmt: skip
        total = run_s + START_IN
        try:

            def synced() -> bool:
                lines = [last_status(out / f"{recording_stem(a)}.jsonl") for a in agents]
                return all(line is not None and line["t_sim"] is not None for line in lines)

            progress.phase(f"{scenario}: synchronizing every agent's clock with the leader's")
            if not wait_for(synced, timeout=40, interval=0.5):
                console.print(f"[red]the agents never synchronized; see {out / 'logs'}[/red]")
                return 1
            identity = run_identity(str(spec["name"]))
            progress.phase(f"running {identity['run_id']}: {total:.0f} s")
            _start_run(kiruna, START_IN, spec["name"], identity["run_id"])
            t0 = time.monotonic()
            while (elapsed := time.monotonic() - t0) < total:
                if not all(fleet.alive(recording_stem(a)) for a in agents):
                    console.print(f"[red]an agent stopped early; see {out / 'logs'}[/red]")
                    break
                progress.run(elapsed, total)
                time.sleep(min(0.5, total - elapsed))
        except KeyboardInterrupt:
            interrupted = True
            console.print("interrupted: stopping agents, links and routers")
        progress.phase("stopping agents (each closes its recording), the links and the routers")
        codes = fleet.stop_all()
    run = {
        **identity,
        "leader": agents[0],
        "scenario": scenario,
        "experiment": spec,
        "agents": {
            p["agent"]: {
                "role": p["role"],
                "platform": p["platform"],
                "follow": p.get("follow"),
                "latency_compensation": compensate,
                "clock_offset": SCENARIO_CLOCKS.get(p["agent"].split("/")[0], 1.5),
                "clock_drift_ppm": 0.0,
            }
            for p in spec["participants"]
        },
        "link": {"delay_ms": delay_ms, "jitter_ms": jitter_ms, "jitter_dist": "normal"},
        "duration_s": run_s,
        "seed": seed,
        "exit_codes": codes,
        "command": " ".join(["fedlab", *sys.argv[1:]]) if sys.argv else "fedlab demo",
        "wall_s": time.monotonic() - started,
    }
    (out / "run.json").write_text(json.dumps(run, indent=1) + "\n")
    summary = _merge_and_report(out, progress, console)
    console.print(scenario_table(summary))
    console.print(_written(out, summary), highlight=False)
    return 130 if interrupted else 0


def scenario_table(summary: dict[str, Any]) -> Table:
    """The scenario's figures: formation error or docking outcome, and the workspace."""
    table = Table(title=f"fedlab demo: {summary.get('scenario', '?')}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    f, d = summary.get("formation"), summary.get("docking")
    if f is not None:
        comp = "compensated" if f.get("latency_compensation") else "not compensated"
        table.add_row("one-way delay (ms)", f"{f.get('delay_ms')}")
        table.add_row(f"formation error RMS (cm), {comp}", f"{f['error_rms_m'] * 100:.2f}")
        table.add_row(f"formation error max (cm), {comp}", f"{f['error_max_m'] * 100:.2f}")
    if d is not None:
        table.add_row("docking success", str(d["success"]))
        rows = (
            ("time_s", 1, "s"),
            ("contact_speed_mps", 100, "cm/s"),
            ("lateral_error_m", 100, "cm"),
            ("heading_error_deg", 1, "deg"),
        )
        for key, scale, unit in rows:
            value = d.get(key)
            table.add_row(f"{key} ({unit})", "-" if value is None else f"{value * scale:.2f}")
    for agent, w in (summary.get("workspace") or {}).items():
        table.add_row(
            f"{agent}: area violations / clamped / holds",
            f"{w['violations']} / {w['clamped']} / {w['holds']}",
        )
    return table

"""``fedlab demo``: the paper's two-lab setup on this machine.

Two lab routers as separate processes (``kiruna`` listens, ``rome`` dials it, as
a lab behind a firewall would), a leader ``kiruna/knatte`` and a follower
``rome/pinocchio`` whose clock is ``clock_offset`` seconds ahead. Every agent
writes status lines; the truth of the offset comes from the host clock they share
(:mod:`federation.status`), so the run reports how far off the estimate is.
"""

from __future__ import annotations

import json
import math
import statistics
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from federation.launch import Fleet, free_port
from federation.status import last_status, read_status, true_offset

__all__ = ["run_demo", "summarize"]

LEADER, FOLLOWER = "kiruna/knatte", "rome/pinocchio"

# The paper's figures (section 4, 600 s validation over the internet; NOTES.md).
PAPER = {
    "offset_std_s": 0.005,
    "delay_median_s": 0.040,
    "delay_std_s": 0.005,
}


def _agent_args(role: str, agent: str, endpoint: str, status: Path, duration: float) -> list[str]:
    lab, name = agent.split("/")
    return [
        "agent",
        "--role",
        role,
        "--lab",
        lab,
        "--name",
        name,
        "-e",
        endpoint,
        "--duration",
        f"{duration}",
        "--status-json",
        str(status),
    ]


def summarize(leader_file: Path, follower_file: Path) -> dict[str, Any]:
    """The follower's view of the leader's clock, against the truth, from status lines."""
    leader_lines = read_status(leader_file)
    follower_lines = read_status(follower_file)
    if not leader_lines or not follower_lines:
        return {}
    truth = true_offset(leader_lines[-1], follower_lines[-1])
    # Per-exchange figures (the last exchange at each status line), as in the paper's plots.
    offsets, delays = [], []
    for line in follower_lines:
        peer = line["peers"].get(LEADER)
        if peer and peer["last_offset"] is not None:
            offsets.append(peer["last_offset"])
            delays.append(peer["last_delay"])
    if not offsets:
        return {"true_offset_s": truth}
    final = follower_lines[-1]["peers"][LEADER]
    return {
        "true_offset_s": truth,
        "offset_estimate_s": final["offset"],
        "offset_error_s": final["offset"] - truth,
        "offset_std_s": statistics.pstdev(offsets),
        "delay_median_s": statistics.median(delays),
        "delay_std_s": statistics.pstdev(delays),
        "sync_samples": final["samples"],
        "sync_rejected": final["rejected"],
        "locked": final["locked"],
    }


def _progress(elapsed: float, duration: float, leader: Path, follower: Path) -> Table:
    table = Table(title=f"fedlab demo: {elapsed:4.1f} / {duration:.0f} s")
    for column in ("agent", "t_exec (s)", "t_sim (s)", "heading (deg)", "offset (s)", "delay (ms)"):
        table.add_column(column, justify="right")
    for agent, path in ((LEADER, leader), (FOLLOWER, follower)):
        line = last_status(path)
        if line is None:
            table.add_row(agent, "starting", "", "", "", "")
            continue
        peer = next(iter(line["peers"].values()), None)
        offset = peer["offset"] if peer else None
        delay = peer["delay"] if peer else None
        table.add_row(
            agent,
            f"{line['t_exec']:.2f}",
            "-" if line["t_sim"] is None else f"{line['t_sim']:.2f}",
            f"{math.degrees(line['pose'][2]):6.2f}",
            "-" if offset is None else f"{offset:+.4f}",
            "-" if delay is None else f"{delay * 1e3:.2f}",
        )
    return table


def run_demo(duration: float, out: Path, clock_offset: float = 26.42) -> int:
    console = Console()
    out.mkdir(parents=True, exist_ok=True)
    leader_file, follower_file = out / "kiruna-knatte.jsonl", out / "rome-pinocchio.jsonl"
    for path in (leader_file, follower_file):
        path.unlink(missing_ok=True)
    kiruna = f"tcp/127.0.0.1:{free_port()}"
    rome = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    interrupted = False
    with Fleet(out / "logs") as fleet:
        fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
        fleet.start("router-rome", ["router", "--lab", "rome", "-l", rome, "-e", kiruna])
        fleet.start("kiruna-knatte", _agent_args("leader", LEADER, kiruna, leader_file, duration))
        follower = _agent_args("follower", FOLLOWER, rome, follower_file, duration)
        follower += ["--follow", LEADER, "--clock-offset", f"{clock_offset}"]
        fleet.start("rome-pinocchio", follower)
        try:
            with Live(
                console=console, refresh_per_second=2, transient=not console.is_terminal
            ) as live:
                while fleet.alive("kiruna-knatte") or fleet.alive("rome-pinocchio"):
                    elapsed = time.monotonic() - started
                    live.update(_progress(elapsed, duration, leader_file, follower_file))
                    if elapsed > duration + 30:  # agents stop themselves; this bounds the wait
                        console.print("[red]agents did not stop in time; stopping them[/red]")
                        break
                    time.sleep(0.5)
        except KeyboardInterrupt:
            interrupted = True
            console.print("interrupted: stopping routers and agents")
    summary = summarize(leader_file, follower_file)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    _print_summary(console, summary, out)
    if interrupted:
        return 130
    return 0 if "offset_error_s" in summary else 1


def _print_summary(console: Console, summary: dict[str, Any], out: Path) -> None:
    if "offset_error_s" not in summary:
        console.print(f"[red]no sync estimate was made; see the logs in {out / 'logs'}[/red]")
        return
    table = Table(title="rome/pinocchio's estimate of kiruna/knatte's clock")
    table.add_column("figure")
    table.add_column("this run", justify="right")
    table.add_column("paper (internet, 600 s)", justify="right")
    table.add_row("true offset (s)", f"{summary['true_offset_s']:.6f}", "26.420 (median)")
    table.add_row("estimated offset (s)", f"{summary['offset_estimate_s']:.6f}", "")
    table.add_row(
        "offset error (ms)", f"{summary['offset_error_s'] * 1e3:+.3f}", "unknown (no truth)"
    )
    table.add_row(
        "offset std (ms)",
        f"{summary['offset_std_s'] * 1e3:.3f}",
        f"{PAPER['offset_std_s'] * 1e3:.0f}",
    )
    table.add_row(
        "delay median (ms)",
        f"{summary['delay_median_s'] * 1e3:.3f}",
        f"{PAPER['delay_median_s'] * 1e3:.1f}",
    )
    table.add_row(
        "delay std (ms)", f"{summary['delay_std_s'] * 1e3:.3f}", f"{PAPER['delay_std_s'] * 1e3:.0f}"
    )
    table.add_row("sync exchanges", str(summary["sync_samples"]), "")
    console.print(table)
    console.print(f"status lines, logs and summary.json in {out}")

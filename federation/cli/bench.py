"""``fedlab bench sync|latency|scale|memory|network|network-formation|scenarios|merge|replay``:
benchmarks, beside
baselines run alongside; ``fedlab bench table``: their headline figures from benchmarks/.

Each parses its flags, runs :mod:`federation.bench` and prints a table (or ``--json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from federation.bench import latency, memory, scale, sync, table
from federation.bench import merge as merge_bench
from federation.cli import bench_network, bench_replay
from federation.cli.common import Formatter, Subparsers, count, positive

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks: sync accuracy, latency, scale, memory, merge, replay",
        formatter_class=Formatter,
        description="Benchmarks; each prints a table, or JSON with --json.",
        epilog=(
            "Examples:\n"
            "  fedlab bench sync --duration 60 --scenario drift\n"
            "  fedlab bench latency --seconds 30 --rate 100 --json\n"
            "  fedlab bench scale --agents 2 --agents 8 --seconds 20\n"
            "  fedlab bench memory --agents 32 --agents 128 --json\n"
            "  fedlab bench network --scenario loss5 --transport multilink --seconds 60\n"
            "  fedlab bench network-formation --seconds 60 --repeats 3 --json-out FILE\n"
            "  fedlab bench scenarios --json > benchmarks/scenarios.json\n"
            "  fedlab bench merge --size 2048 --json-out benchmarks/merge-2gib.json\n"
            "  fedlab bench replay --repeats 3 --json-out benchmarks/replay-paper.json\n"
            "  fedlab bench table   # the README's table, from benchmarks/"
        ),
    )
    benches = p.add_subparsers(dest="bench", required=True, metavar="BENCH")
    _add_sync(benches)
    _add_latency(benches)
    _add_scale(benches)
    _add_memory(benches)
    bench_network.add_network(benches)
    bench_network.add_network_formation(benches)
    _add_scenarios(benches)
    _add_merge(benches)
    bench_replay.add_replay(benches)
    _add_table(benches)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark named by ``args.bench`` and print its results."""
    runs = {"sync": _run_sync, "latency": _run_latency, "scale": _run_scale}
    runs |= {"memory": _run_memory, "network": bench_network.run_network}
    runs |= {"scenarios": _run_scenarios, "merge": _run_merge, "table": _run_table}
    runs |= {"network-formation": bench_network.run_network_formation}
    runs |= {"replay": bench_replay.run_replay}
    return runs[args.bench](args)


# -- sync ----------------------------------------------------------------------------
def _after_sync_phase(text: str) -> float:
    """Argument type: seconds longer than the paper's sync phase (nothing is scored before)."""
    value = positive(text)
    if value <= sync.SYNC_PHASE:
        raise argparse.ArgumentTypeError(
            f"must exceed the {sync.SYNC_PHASE:g} s sync phase, not {text!r}"
        )
    return value


def _add_sync(benches: Subparsers) -> None:
    p = benches.add_parser(
        "sync",
        help="offset error of each estimator under emulated internet paths",
        formatter_class=Formatter,
        description=(sync.__doc__ or "").split("\n\n")[1],
        epilog=(
            "Examples:\n"
            "  fedlab bench sync --duration 60 --scenario paper-like --scenario drift\n"
            "  fedlab bench sync --offline --duration 600 --json\n"
            "  fedlab bench sync --replay runs/bench-network-tcp-tuned/loss20-tcp-tuned-0\n"
            "  fedlab bench sync --replay benchmarks/data/testbed-sync-exchanges.json.gz"
        ),
    )
    p.add_argument(
        "--scenario", action="append", choices=sorted(sync.SCENARIOS), metavar="NAME",
        help=f"scenario to run (repeatable; default all: {', '.join(sync.SCENARIOS)})",
    )  # fmt: skip
    p.add_argument(
        "--estimator", action="append", choices=sync.ESTIMATORS, metavar="NAME",
        help=f"estimator to score (repeatable; default all: {', '.join(sync.ESTIMATORS)})",
    )  # fmt: skip
    p.add_argument(
        "--duration", type=_after_sync_phase, default=60.0, metavar="S",
        help="seconds per scenario",
    )  # fmt: skip
    p.add_argument("--offline", action="store_true", help="draw exchanges from the link model")
    p.add_argument("--seed", type=int, default=1, help="random seed of the link emulator")
    p.add_argument(
        "--trial", type=_after_sync_phase, default=60.0, metavar="S",
        help="seconds of each fresh start scored under 'restarts' (one every 10 s)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-sync"), metavar="DIR", help="run folder"
    )
    p.add_argument(
        "--replay", action="append", type=Path, metavar="PATH",
        help="score recorded exchanges instead of running scenarios (repeatable): a run "
        "folder with follower.mcap and leader.mcap, or a file written by --save",
    )  # fmt: skip
    p.add_argument(
        "--save", type=Path, metavar="FILE",
        help="with --replay: write the recordings read to FILE (gzip JSON)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _run_sync(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    estimators = args.estimator or sync.ESTIMATORS
    if args.save and not args.replay:
        raise SystemExit("fedlab bench sync: --save needs --replay (the recordings to save)")
    if args.replay:
        try:
            recordings = sync.load_runs(args.replay)
            results = sync.replay_runs(recordings, estimators)
        except ValueError as e:
            raise SystemExit(f"fedlab bench sync: {e}") from None
        if args.save:
            sync.save_recordings(args.save, recordings)
    else:
        scenarios = [sync.SCENARIOS[n] for n in (args.scenario or sync.SCENARIOS)]
        results = sync.run(
            scenarios, estimators, args.duration, args.offline, args.out,
            args.seed, progress=console.print, trial=args.trial,
        )  # fmt: skip
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    table = Table(title="clock offset |error| after the sync phase (ms)")
    for col in ("scenario", "estimator", "p50", "p95", "max", "n", "restarts p50", "p95 ",
                "starts"):  # fmt: skip
        table.add_column(col, justify="left" if col in ("scenario", "estimator") else "right")
    for r in results:
        again = r["restarts"]
        table.add_row(
            r["scenario"], r["estimator"],
            *(f"{r[k] * 1e3:.3f}" for k in ("p50", "p95", "max")), str(r["n"]),
            *((f"{again['p50'] * 1e3:.3f}", f"{again['p95'] * 1e3:.3f}", str(again["trials"]))
              if again else ("-", "-", "0")),
        )  # fmt: skip
    Console(width=max(Console().width, 100)).print(table)
    return 0


# -- latency -------------------------------------------------------------------------
def _add_latency(benches: Subparsers) -> None:
    p = benches.add_parser(
        "latency",
        help="pose latency across two routers, beside bare zenoh and raw UDP",
        formatter_class=Formatter,
        description=(latency.__doc__ or "").split("\n\n")[0],
        epilog="Example: fedlab bench latency --seconds 30 --rate 100 --json",
    )
    p.add_argument("--seconds", type=positive, default=20.0, metavar="S", help="seconds per path")
    p.add_argument("--rate", type=positive, default=100.0, metavar="HZ", help="samples per second")
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-latency"), metavar="DIR", help="run folder"
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _run_latency(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    result = latency.run(args.seconds, args.rate, args.out)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    table = Table(title=f"one-way latency, loopback, two routers ({args.rate:.0f} Hz)")
    for col in ("path", "p50 (ms)", "p99 (ms)", "max (ms)", "samples"):
        table.add_column(col, justify="left" if col == "path" else "right")
    for name in latency.PATHS:
        r = result[name]
        table.add_row(
            name, f"{r['p50_ms']:.3f}", f"{r['p99_ms']:.3f}", f"{r['max_ms']:.3f}", str(r["n"])
        )
    console = Console()
    console.print(table)
    console.print(
        f"fedlab / bare zenoh p50: {result['ratio_p50_fedlab_over_bare']:.2f}x; "
        f"bare zenoh / raw udp p50: {result['ratio_p50_bare_over_udp']:.1f}x"
    )
    return 0


# -- scale ---------------------------------------------------------------------------
def _agents(text: str) -> int:
    """Argument type: an agent count of at least 2 (a leader and a follower)."""
    if (n := count(text)) < 2:
        raise argparse.ArgumentTypeError(f"at least 2 (a leader and a follower), not {text!r}")
    return n


def _add_scale(benches: Subparsers) -> None:
    p = benches.add_parser(
        "scale",
        help=f"N agents over {scale.LABS} labs: CPU, latency and loss as N grows",
        formatter_class=Formatter,
        description=(scale.__doc__ or "").split("\n\n")[0],
        epilog="Example: fedlab bench scale --agents 2 --agents 8 --seconds 20 --json",
    )
    p.add_argument(
        "--agents", action="append", type=_agents, metavar="N",
        help="agent counts to run (repeatable; default "
        f"{' '.join(map(str, scale.DEFAULT_AGENTS))})",
    )  # fmt: skip
    p.add_argument("--seconds", type=positive, default=20.0, metavar="S", help="seconds per N")
    p.add_argument(
        "--settle", type=positive, default=scale.SETTLE, metavar="S",
        help="seconds from the workers' start before samples count: discovery and routes "
        f"(default {scale.SETTLE:g}; each run lasts settle + seconds)",
    )  # fmt: skip
    p.add_argument(
        "--mode", action="append", choices=scale.MODES,
        help="configurations to run (repeatable; default all: default = no sync_with, "
        "tuned = followers sync_with the leader, bare = bare zenoh-python, the floor)",
    )  # fmt: skip
    p.add_argument(
        "--labs", type=count, default=scale.LABS, metavar="L",
        help=f"labs (routers and worker processes; default {scale.LABS})",
    )  # fmt: skip
    p.add_argument(
        "--runs", type=count, default=1, metavar="K",
        help="repeats of the whole set, interleaved (medians and spread over them)",
    )  # fmt: skip
    p.add_argument(
        "--group", type=count, default=scale.GROUP, metavar="G",
        help="agents of a worker that tick on one wake-up, fedlab and bare alike (default "
        f"{scale.GROUP}; 8 costs a third less CPU, with bursts: docs/scale.md)",
    )  # fmt: skip
    p.add_argument(
        "--pin-routers", action="store_true",
        help="routers on a core of their own (fedlab router --cpus), the workers on the "
        "others, fedlab and bare alike (needs 2 cores; docs/scale.md)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-scale"), metavar="DIR", help="run folder"
    )
    p.add_argument(
        "--json", action="store_true",
        help="print JSON (the rows, and with several runs or modes the summary) instead of a table",
    )  # fmt: skip


def _run_scale(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    modes = tuple(args.mode or scale.MODES)

    def progress(k: int, n: int, mode: str) -> None:
        console.print(f"run {k + 1}/{args.runs}: {n} agents, {mode}: {args.seconds:.0f} s")

    results = scale.run(list(args.agents or scale.DEFAULT_AGENTS), args.seconds, args.out,
                        modes, args.labs, args.runs, args.group, progress,
                        args.pin_routers, args.settle)  # fmt: skip
    if args.json:
        if args.runs == 1 and len(modes) == 1:
            print(json.dumps(results, indent=1))
        else:
            print(json.dumps({"rows": results, "summary": scale.summary(results)}, indent=1))
        return 0
    hosting = ", routers on a core of their own" if args.pin_routers else ""
    table = Table(title=f"N agents over {args.labs} labs (pose 20 Hz, sync 10 Hz{hosting})")
    cols = ("run", "agents", "mode", "CPU (cores)", "CPU/agent", "p50 (ms)", "p99 (ms)",
            "loss", "holds", "leader gap max (ms, steady / all)", "sync/s", "RSS MiB (first, last)",
            "busiest worker threads (ms/agent-s)")  # fmt: skip
    for col in cols:
        table.add_column(col, justify="right")
    for r in results:
        rss = r["rss_mib"]
        busiest = sorted(r["worker_threads_ms"].items(), key=lambda kv: -kv[1])[:2]
        table.add_row(
            str(r["run"] + 1), str(r["n"]), r["mode"], f"{r['cpu_cores']:.2f}",
            f"{r['cpu_per_agent'] * 1e3:.1f} m", f"{r['p50_ms']:.2f}", f"{r['p99_ms']:.2f}",
            f"{r['loss']:.4f}", str(r["stale_holds"]) if "stale_holds" in r else "-",
            f"{r['leader_gap_max_ms']:.0f} / {r['leader_gap_max_all_ms']:.0f}",
            f"{r['sync_per_s']:.0f}",
            f"{rss[0][1]:.0f}, {rss[-1][1]:.0f}" if rss else "-",
            ", ".join(f"{name} {ms:.2f}" for name, ms in busiest) or "-",
        )  # fmt: skip
    Console().print(table)
    for n, entry in scale.summary(results).items():
        for key, value in entry["ratios"].items():
            Console().print(
                f"{n} agents: {key} median {value['median']:.2f} "
                f"({value['min']:.2f}-{value['max']:.2f})"
            )
    return 0


# -- memory --------------------------------------------------------------------------
def _add_memory(benches: Subparsers) -> None:
    p = benches.add_parser(
        "memory",
        help="resident memory per agent hosted in one process, beside bare zenoh-python",
        formatter_class=Formatter,
        description=(memory.__doc__ or "").split("\n\n")[0],
        epilog="Example: fedlab bench memory --agents 32 --agents 128 --json",
    )
    p.add_argument(
        "--agents", action="append", type=count, metavar="N",
        help="agents added to a leader and a follower (repeatable; default "
        f"{' '.join(map(str, memory.DEFAULT_AGENTS))})",
    )  # fmt: skip
    p.add_argument(
        "--mode", action="append", choices=memory.MODES,
        help="default = fedlab agents, bare = bare zenoh-python agents (repeatable; default both)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON rows instead of a table")


def _run_memory(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    rows = memory.run(list(args.agents or memory.DEFAULT_AGENTS), tuple(args.mode or memory.MODES))
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    table = Table(title="Resident memory, agents hosted in one process")
    for col in ("agents added", "mode", "base (MiB)", "with them (MiB)", "per agent (KiB)",
                "agents each saw"):  # fmt: skip
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["n"]), r["mode"], f"{r['base_mib']:.1f}", f"{r['rss_mib']:.1f}",
            f"{r['kib_per_agent']:.0f}", str(r["peers_seen"]),
        )  # fmt: skip
    Console().print(table)
    return 0


# -- scenarios -----------------------------------------------------------------------
def _add_scenarios(benches: Subparsers) -> None:
    from federation.bench import scenarios

    p = benches.add_parser(
        "scenarios",
        help="formation, docking, adaptive gains and transparency ratios in simulated time",
        formatter_class=Formatter,
        description=(scenarios.__doc__ or "").split("\n\n")[0],
        epilog="Example: fedlab bench scenarios --seeds 3 --docking-seeds 10 --json",
    )
    p.add_argument(
        "--experiments", type=Path, default=Path("deploy/experiments"), metavar="DIR",
        help="folder holding formation.toml, docking.toml and attitude-tracking.toml",
    )  # fmt: skip
    p.add_argument(
        "--seeds", type=int, default=3, metavar="N", help="formation and transparency seeds"
    )
    p.add_argument("--docking-seeds", type=int, default=10, metavar="N", help="docking seeds")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")


def _run_scenarios(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from federation.bench import scenarios

    if args.seeds < 1 or args.docking_seeds < 1:
        print("fedlab bench scenarios: error: --seeds and --docking-seeds must be >= 1")
        return 2
    result = scenarios.run(args.experiments, args.seeds, args.docking_seeds)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    console = Console()
    table = Table(title=f"formation error, {args.seeds} seeds (cm)")
    for col in ("one-way delay (ms)", "compensation", "RMS per seed", "max per seed", "workspace"):
        table.add_column(col)
    for row in result["formation"]:
        table.add_row(
            f"{row['delay_s'] * 1e3:.0f}",
            "on" if row["latency_compensation"] else "off",
            ", ".join(f"{v * 100:.2f}" for v in row["error_rms_m"]),
            ", ".join(f"{v * 100:.2f}" for v in row["error_max_m"]),
            str(sum(row["workspace_events"])),
        )
    console.print(table)
    d = result["docking"]
    table = Table(
        title=f"docking over {d['delay_s'] * 1e3:.0f} ms: {d['successes']} of {d['seeds']}"
    )
    for col in ("figure", "median", "worst"):
        table.add_column(col)
    for key, stats in d["stats"].items():
        table.add_row(key, f"{stats['median']:.4g}", f"{stats['max']:.4g}")
    console.print(table)
    table = Table(title="adaptive gains: follower heading error (deg)")
    for col in ("maneuver", "fixed RMS / max", "adaptive RMS / max", "scale"):
        table.add_column(col)
    for row in result["adaptive"]:
        f, a = row["fixed"], row["adaptive"]
        table.add_row(
            f"{row['amplitude_deg']:.0f} deg in {row['maneuver_s']:.0f} s",
            f"{f['heading_error_rms_deg']:.2f} / {f['heading_error_max_deg']:.2f}",
            f"{a['heading_error_rms_deg']:.2f} / {a['heading_error_max_deg']:.2f}",
            f"{a['scale_max']:.2f}",
        )
    console.print(table)
    console.print(_transparency_table(result["transparency"]))
    return 0


def _transparency_table(rows: list[dict[str, Any]]) -> Any:
    from rich.table import Table

    table = Table(title="transparency: tracking error with the delay / with none, same seeds")
    for col in ("scenario", "one-way delay (ms)", "compensation", "ratio median (min to max)"):
        table.add_column(col)
    for row in rows:
        r = row["ratio_stats"]
        table.add_row(
            row["scenario"],
            f"{row['delay_s'] * 1e3:.0f}",
            "on" if row["latency_compensation"] else "off",
            "-" if r["median"] is None else f"{r['median']:.3f} ({r['min']:.3f} to {r['max']:.3f})",
        )
    return table


# -- merge ---------------------------------------------------------------------------
def _add_merge(benches: Subparsers) -> None:
    p = benches.add_parser(
        "merge",
        help="peak memory and MiB/s of fedlab merge on a large synthetic run, beside a plain read",
        formatter_class=Formatter,
        description=(merge_bench.__doc__ or "").split("\n\n")[0],
        epilog=(
            "Examples:\n"
            "  fedlab bench merge --size 64 --repeats 1\n"
            "  fedlab bench merge --size 2048 --json-out benchmarks/merge-2gib.json"
        ),
    )
    p.add_argument(
        "--size", type=positive, default=merge_bench.DEFAULT_SIZE_MIB, metavar="MIB",
        help="MiB of recordings in all, across the agents' files",
    )  # fmt: skip
    p.add_argument(
        "--agents", type=_agents, default=merge_bench.DEFAULT_AGENTS, metavar="N",
        help="agents recorded: a leader (the reference) and N-1 followers",
    )  # fmt: skip
    p.add_argument(
        "--repeats", type=count, default=merge_bench.DEFAULT_REPEATS, metavar="N",
        help="merges (each beside a baseline read) of the one run written",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=1, help="seed of the synthetic run")
    p.add_argument(
        "--budget", type=positive, default=merge_bench.BUDGET_MIB, metavar="MIB",
        help="peak resident memory the merge may reach; past it the command fails (exit 1)",
    )  # fmt: skip
    p.add_argument(
        "--dir", type=Path, default=None, metavar="DIR",
        help="where the run's temporary folder is made (default: the system's temporary "
        "folder); deleted afterwards",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--json-out", type=Path, metavar="FILE", help="also write the JSON to FILE")


def _run_merge(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    try:
        result = merge_bench.run(
            args.size, args.agents, args.repeats, args.seed, args.budget, args.dir,
            progress=console.print,
        )  # fmt: skip
    except (ValueError, RuntimeError, OSError) as error:
        print(f"fedlab bench merge: error: {error}", file=sys.stderr)
        return 1
    result["command"] = "fedlab bench merge " + " ".join(
        f"--{k} {v}" for k, v in (("size", f"{args.size:g}"), ("agents", args.agents),
                                   ("repeats", args.repeats), ("seed", args.seed),
                                   ("budget", f"{args.budget:g}"))
    )  # fmt: skip
    text = json.dumps(result, indent=1)
    if args.json_out is not None:
        args.json_out.write_text(text + "\n", encoding="utf-8")
    if args.json:
        print(text)
    else:
        table = Table(title=f"fedlab merge, {result['run']['mib']:.0f} MiB of recordings")
        for col in ("", "peak RSS (MiB)", "MiB/s", "wall (s)"):
            table.add_column(col, justify="right")
        for what in ("merge", "baseline"):
            r = result[what]
            table.add_row(
                what, *(f"{r[k]['median']:.2f} ({r[k]['min']:.2f} to {r[k]['max']:.2f})"
                        for k in ("peak_rss_mib", "mib_per_s", "wall_s")),
            )  # fmt: skip
        Console().print(table)
    try:
        merge_bench.check(result)
    except merge_bench.BudgetExceeded as error:
        print(f"fedlab bench merge: {error}", file=sys.stderr)
        return 1
    return 0


# -- table ---------------------------------------------------------------------------
def _add_table(benches: Subparsers) -> None:
    p = benches.add_parser(
        "table",
        help="the benchmarks' headline figures as a Markdown table, from their result files",
        formatter_class=Formatter,
        description=(
            "Print one Markdown table of every benchmark's headline figures, read from the\n"
            "committed result files (benchmarks/README.md says which command made each).\n"
            "The README's benchmark table is this output; a test fails when they differ."
        ),
        epilog="Example:\n  fedlab bench table --dir benchmarks",
    )
    p.add_argument(
        "--dir",
        type=Path,
        default=Path("benchmarks"),
        metavar="DIR",
        help="the folder of result files",
    )
    p.add_argument(
        "--link-prefix",
        default="benchmarks/",
        metavar="PREFIX",
        help="what each file's link starts with (docs/ pages: ../benchmarks/)",
    )


def _run_table(args: argparse.Namespace) -> int:
    try:
        print(table.table_markdown(args.dir, args.link_prefix), end="")
    except (OSError, KeyError, ValueError) as error:
        print(f"fedlab bench table: error: {args.dir}: {error}", file=sys.stderr)
        return 1
    return 0

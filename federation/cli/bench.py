"""``fedlab bench sync|latency|scale|memory|network|network-formation|scenarios|merge``:
benchmarks, beside
baselines run alongside; ``fedlab bench table``: their headline figures from benchmarks/.

Each parses its flags, runs :mod:`federation.bench` and prints a table (or ``--json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from federation.bench import latency, memory, scale, sync, table
from federation.bench import merge as merge_bench
from federation.cli.common import Formatter, Subparsers, positive

__all__ = ["add", "run"]


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmarks: sync accuracy, latency, scale, memory, merge",
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
            "  fedlab bench table   # the README's table, from benchmarks/"
        ),
    )
    benches = p.add_subparsers(dest="bench", required=True, metavar="BENCH")
    _add_sync(benches)
    _add_latency(benches)
    _add_scale(benches)
    _add_memory(benches)
    _add_network(benches)
    _add_network_formation(benches)
    _add_scenarios(benches)
    _add_merge(benches)
    _add_table(benches)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark named by ``args.bench`` and print its results."""
    runs = {"sync": _run_sync, "latency": _run_latency, "scale": _run_scale}
    runs |= {"memory": _run_memory, "network": _run_network, "scenarios": _run_scenarios}
    runs |= {"merge": _run_merge, "table": _run_table}
    runs |= {"network-formation": _run_network_formation}
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
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if n < 2:
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
        "--mode", action="append", choices=scale.MODES,
        help="configurations to run (repeatable; default all: default = no sync_with, "
        "tuned = followers sync_with the leader, bare = bare zenoh-python, the floor)",
    )  # fmt: skip
    p.add_argument(
        "--labs", type=_agents_or_one, default=scale.LABS, metavar="L",
        help=f"labs (routers and worker processes; default {scale.LABS})",
    )  # fmt: skip
    p.add_argument(
        "--runs", type=_agents_or_one, default=1, metavar="K",
        help="repeats of the whole set, interleaved (medians and spread over them)",
    )  # fmt: skip
    p.add_argument(
        "--group", type=_agents_or_one, default=scale.GROUP, metavar="G",
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


def _agents_or_one(text: str) -> int:
    """Argument type: a count of at least 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"at least 1, not {text!r}")
    return n


def _run_scale(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    console = Console(stderr=True)
    modes = tuple(args.mode or scale.MODES)

    def progress(k: int, n: int, mode: str) -> None:
        console.print(f"run {k + 1}/{args.runs}: {n} agents, {mode}: {args.seconds:.0f} s")

    results = scale.run(list(args.agents or scale.DEFAULT_AGENTS), args.seconds, args.out,
                        modes, args.labs, args.runs, args.group, progress,
                        args.pin_routers)  # fmt: skip
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
        "--agents", action="append", type=_agents_or_one, metavar="N",
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


# -- network -------------------------------------------------------------------------
_NETWORK_SCENARIOS = ("clean", "loss1", "loss5", "loss20", "cut10", "mtu576")
_NETWORK_TRANSPORTS = ("multilink", "tcp", "tcp-tuned", "tls", "quic", "quic-stream")


def _add_network(benches: Subparsers) -> None:
    p = benches.add_parser(
        "network",
        help="the federation on real network stacks (namespaces, NAT, loss, cuts, MTU); root",
        formatter_class=Formatter,
        description=(
            "Two labs in network namespaces (Rome behind NAT and a stateful firewall),\n"
            "the paper's path between them (40 ms one way, 3 ms jitter) with loss, a cut\n"
            "or a path-MTU black hole, routers from deploy/routers/, a leader, a follower\n"
            "and an outside subscriber. Needs root, nftables and /dev/net/tun."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab bench network --scenario loss5 --transport multilink --transport tcp\n"
            "  fedlab bench network --seconds 60 --repeats 2 --json-out benchmarks/network.json\n"
            "  fedlab bench network --deployment generated --scenario loss5 --repeats 3"
        ),
    )
    p.add_argument(
        "--scenario", action="append", choices=_NETWORK_SCENARIOS, metavar="NAME",
        help=f"scenario (repeatable; default all: {', '.join(_NETWORK_SCENARIOS)})",
    )  # fmt: skip
    p.add_argument(
        "--transport", action="append", choices=_NETWORK_TRANSPORTS, metavar="NAME",
        help="multilink: deploy/routers/multilink (TCP + UDP links); tcp: deploy/routers; "
        "tcp-tuned: deploy/routers on hosts with deploy/sysctl; tls: tcp-tuned with the "
        "generated deployment's mutual-TLS lab link; quic: the same on QUIC, pose as "
        "datagrams (mixed_rel); quic-stream: QUIC, one stream (repeatable; default tcp-tuned)",
    )  # fmt: skip
    p.add_argument(
        "--seconds", type=positive, default=60.0, metavar="S",
        help="seconds scored per run, after the 10 s sync phase",
    )  # fmt: skip
    p.add_argument(
        "--cfg", action="append", default=[], metavar="KEY:VALUE",
        help="a Zenoh setting for both routers and both agents, not the outside subscriber "
        "(repeatable), e.g. transport/unicast/lowlatency:true",
    )  # fmt: skip
    p.add_argument(
        "--deployment", choices=("bench", "generated"), default="bench",
        help="bench: the bench's routers and agents with --transport's lab link; generated: "
        "the files fedlab deploy generate writes (its lab link, access control, size and rate "
        "limits; agents over TLS, a run started by ctl), without --transport or --cfg",
    )  # fmt: skip
    p.add_argument("--repeats", type=int, default=1, metavar="N", help="runs per scenario")
    p.add_argument("--seed", type=int, default=1, help="the packet stage's first seed")
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-network"), metavar="DIR", help="run folder"
    )
    p.add_argument("--json-out", type=Path, metavar="FILE", help="also write the results here")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _run_network(args: argparse.Namespace) -> int:
    import shlex
    import sys

    from rich.console import Console
    from rich.table import Table

    from federation.testbed import missing

    why = missing()
    if why is not None:
        raise SystemExit(f"fedlab bench network: {why}")
    names = args.scenario or list(_NETWORK_SCENARIOS)
    transports = args.transport or ["tcp-tuned"]
    for item in args.cfg:
        if ":" not in item.strip(":"):
            raise SystemExit(f"fedlab bench network: --cfg {item!r}: expected KEY:VALUE")
    command = shlex.join(["fedlab", *sys.argv[1:]])

    def save(results: list[dict[str, Any]]) -> None:
        if args.json_out is not None:  # after every run: a long bench keeps what it measured
            args.json_out.parent.mkdir(parents=True, exist_ok=True)
            document = {"command": command, "results": results}
            args.json_out.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")

    results = _network_results(args, names, transports, save)
    save(results)
    document = {"command": command, "results": results}
    if args.json:
        print(json.dumps(document, indent=1))
        return 0
    table = Table(title="federation on the testbed (40 ms one way, 3 ms jitter, Rome behind NAT)")
    cols = ("scenario", "transport", "holds/min", "held", "pose p99 ms", "sync p95 ms",
            "heading max deg", "cut: hold ms", "back s")  # fmt: skip
    for col in cols:
        table.add_column(col, justify="left" if col in cols[:2] else "right")
    for r in results:
        if "error" in r:
            table.add_row(r["scenario"]["name"], r["transport"], f"failed: {r['error'][:80]}")
            continue
        cut = r.get("cut") or {}
        back = [cut.get(k) for k in ("pose_back_after_s", "sync_back_after_s")]
        table.add_row(
            r["scenario"]["name"], r["transport"], f"{r['holds_per_min']:.1f}",
            f"{r['held_fraction']:.1%}", _num(r["pose_latency_ms"]["p99"]),
            _num(r["sync_error_ms"]["p95"], 3), _num(r["heading_error_deg"]["max"], 3),
            _num(cut.get("hold_after_cut_ms")),
            "-" if None in back else f"{max(b for b in back if b is not None):.2f}",
        )  # fmt: skip
    Console(width=max(Console().width, 120)).print(table)
    return 0


def _network_results(
    args: argparse.Namespace,
    names: list[str],
    transports: list[str],
    save: Callable[[list[dict[str, Any]]], None],
) -> list[dict[str, Any]]:
    """The runs of the bench's own deployment, or of the generated one."""
    from federation.bench import network

    if args.deployment == "bench":
        return network.run(
            names, transports, args.seconds, args.out, args.repeats, args.seed, args.cfg, save
        )
    if args.transport or args.cfg:
        raise SystemExit(
            "fedlab bench network: --deployment generated runs the generated files as they "
            "are: its lab link is the one fedlab deploy generate writes, so --transport and "
            "--cfg do not apply"
        )
    from federation.bench import generated

    return generated.run(names, args.seconds, args.out, args.repeats, args.seed, save)


def _num(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


# -- network-formation ---------------------------------------------------------------
# A subcommand of its own rather than a `bench network` scenario: `network`'s scenarios
# name paths for the attitude leader/follower pair, scored run by run; this one flies
# another experiment (three labs) at several losses and scores each against a no-loss
# run of the same invocation.
def _loss(text: str) -> float:
    """A loss fraction in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"{text}: a loss is a fraction from 0 to below 1")
    return value


def _add_network_formation(benches: Subparsers) -> None:
    from federation.bench import formation_network

    p = benches.add_parser(
        "network-formation",
        help="the formation across three labs in the network testbed under loss: its "
        "transparency ratio; root",
        formatter_class=Formatter,
        description=(
            "The formation experiment (three labs, three agents) in the network testbed:\n"
            "Kiruna public, Rome and a third lab behind Rome's NAT and stateful firewall,\n"
            "the paper's path (40 ms one way, 3 ms jitter) with random loss. Each loss\n"
            "level is flown --repeats times, interleaved with runs at no loss; the ratio\n"
            "is each repeat's formation error (slot error RMS, the report's figure) over\n"
            "the same repeat's with no loss. Needs root, nftables and /dev/net/tun."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab bench network-formation --seconds 20 --repeats 1\n"
            "  fedlab bench network-formation --seconds 60 --repeats 3 \\\n"
            "      --json-out benchmarks/network-formation-60s.json"
        ),
    )
    p.add_argument(
        "--loss", action="append", type=_loss, metavar="P",
        help="loss fraction on the path, each way (repeatable; 0 is always flown as the "
        "baseline; default: "
        + ", ".join(f"{x:g}" for x in formation_network.LOSSES if x) + ")",
    )  # fmt: skip
    p.add_argument(
        "--seconds", type=positive, default=60.0, metavar="S",
        help="s of run time per run (the experiment's own: 90)",
    )  # fmt: skip
    p.add_argument(
        "--repeats", type=_agents_or_one, default=3, metavar="N", help="runs per loss level"
    )
    p.add_argument("--seed", type=int, default=1, help="first repeat's seed (stage and noise)")
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-network-formation"), metavar="DIR",
        help="run folder (one per run: loss<percent>-<repeat>)",
    )  # fmt: skip
    p.add_argument("--json-out", type=Path, metavar="FILE", help="also write the results here")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def _run_network_formation(args: argparse.Namespace) -> int:
    import shlex

    from rich.console import Console

    from federation.bench import formation_network
    from federation.testbed import missing

    why = missing()
    if why is not None:
        print(f"fedlab bench network-formation: error: {why}", file=sys.stderr)
        return 1
    losses = [0.0, *sorted({x for x in (args.loss or formation_network.LOSSES) if x > 0})]
    command = shlex.join(["fedlab", *sys.argv[1:]])

    def document(runs: list[dict[str, Any]]) -> dict[str, Any]:
        return {
            "command": command,
            "runs": runs,
            "ratios": formation_network.ratios(runs),
            "ratios_after_ramp": formation_network.ratios(runs, "error_rms_after_ramp_m"),
        }

    def save(runs: list[dict[str, Any]]) -> None:
        if args.json_out is not None:  # after every run: a long bench keeps what it measured
            args.json_out.parent.mkdir(parents=True, exist_ok=True)
            text = json.dumps(document(runs), indent=1) + "\n"
            args.json_out.write_text(text, encoding="utf-8")

    progress = Console(stderr=True)

    def step(runs: list[dict[str, Any]]) -> None:
        r = runs[-1]
        what = r.get("error") or f"slot error RMS {r['error_rms_m'] * 100:.2f} cm"
        progress.print(f"loss {r['loss']:g}, repeat {r['repeat']}: {what}", highlight=False)
        save(runs)

    result = formation_network.run(args.seconds, args.repeats, args.out, losses, args.seed, step)
    result = {"command": command, **result}
    if args.json_out is not None:
        args.json_out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        Console().print(_formation_table(result["ratios"], "the whole run"))
        Console().print(_formation_table(result["ratios_after_ramp"], "the circle only"))
    failed = [r for r in result["runs"] if "error" in r]
    for r in failed:
        print(f"loss {r['loss']:g}, repeat {r['repeat']}: failed: {r['error']}", file=sys.stderr)
    return 1 if failed else 0


def _formation_table(rows: list[dict[str, Any]], over: str) -> Any:
    from rich.table import Table

    title = f"formation across the testbed: slot error under loss / with none, {over}"
    table = Table(title=title)
    for col in ("loss", "error, each repeat (cm)", "no loss (cm)", "ratio median (min to max)"):
        table.add_column(col, justify="right")
    for row in rows:
        s = row["ratio_stats"]
        table.add_row(
            f"{row['loss']:.0%}",
            ", ".join("-" if e is None else f"{e * 100:.2f}" for e in row["error_m"]),
            ", ".join("-" if e is None else f"{e * 100:.2f}" for e in row["baseline_m"]),
            "-" if s["median"] is None
            else f"{s['median']:.3f} ({s['min']:.3f} to {s['max']:.3f})",
        )  # fmt: skip
    return table


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
        "--repeats", type=_agents_or_one, default=merge_bench.DEFAULT_REPEATS, metavar="N",
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

"""``fedlab bench network`` and ``fedlab bench network-formation``: the federation in
the network testbed (:mod:`federation.testbed`), the attitude pair on a scenario's path
and the formation's transparency under loss. Parses, runs :mod:`federation.bench`,
prints a table (or ``--json``).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from federation.cli.common import Formatter, Subparsers, count, positive

__all__ = ["add_network", "add_network_formation", "run_network", "run_network_formation"]


# -- network -------------------------------------------------------------------------
_NETWORK_SCENARIOS = ("clean", "loss1", "loss5", "loss20", "cut10", "mtu576")
_NETWORK_TRANSPORTS = ("multilink", "tcp", "tcp-tuned", "tls", "quic", "quic-stream")


def add_network(benches: Subparsers) -> None:
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


def run_network(args: argparse.Namespace) -> int:
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


def add_network_formation(benches: Subparsers) -> None:
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
    p.add_argument("--repeats", type=count, default=3, metavar="N", help="runs per loss level")
    p.add_argument("--seed", type=int, default=1, help="first repeat's seed (stage and noise)")
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench-network-formation"), metavar="DIR",
        help="run folder (one per run: loss<percent>-<repeat>)",
    )  # fmt: skip
    p.add_argument("--json-out", type=Path, metavar="FILE", help="also write the results here")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run_network_formation(args: argparse.Namespace) -> int:

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

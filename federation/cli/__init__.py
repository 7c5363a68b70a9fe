"""``fedlab`` command line: parse, call the library, turn errors into clear messages.

Every command that opens a Zenoh session takes Zenoh's usual flags
(-m/--mode, -e/--connect, -l/--listen, -c/--config, --cfg KEY:VALUE).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from federation.cli.common import (
    Formatter,
    add_zenoh_flags,
    open_interruptible,
    stop_on_signals,
    zenoh_options,
)
from federation.runtime.session import ZenohConfigError
from schemas.config import AgentConfig, ConfigError, load_model, validate

__all__ = ["main"]

log = logging.getLogger("fedlab")


def _version() -> str:
    try:
        return version("fedlab")
    except PackageNotFoundError:
        return "unknown"


# -- router --------------------------------------------------------------------
def cmd_router(args: argparse.Namespace) -> int:
    from federation.runtime.router import load_router_config, run_router

    settings, conf = load_router_config(zenoh_options(args), args.lab)
    run_router(settings, conf, stop_on_signals())
    return 0


# -- agent ---------------------------------------------------------------------
_AGENT_FLAGS = (
    "federation",
    "lab",
    "name",
    "role",
    "follow",
    "sync_with",
    "sync_period",
    "sync_others_period",
    "sync_timeout",
    "sync_window",
    "estimator",
    "four_timestamps",
    "pose_rate",
    "status_period",
    "clock_offset",
    "clock_drift_ppm",
    "clock_step",
    "stale_after",
    "duration",
    "status_json",
    "record",
    "wait_start",
    "platform",
    "seed",
    "latency_compensation",
)


def agent_config(args: argparse.Namespace) -> AgentConfig:
    """The agent's file (if any), then its part in an experiment (if any), overlaid
    with the flags given on the command line."""
    data: dict[str, Any] = {}
    sources = []
    if args.agent_config is not None:
        base = load_model(AgentConfig, args.agent_config)
        data = base.model_dump(exclude_unset=True)
        sources.append(str(args.agent_config))
    if args.experiment is not None:
        data |= _experiment_part(args)
        sources.append(str(args.experiment))
    source = " + ".join([*sources, "command line"])
    for name in _AGENT_FLAGS:
        value = getattr(args, name)
        if value is not None and value != []:
            data[name] = value
    return validate(AgentConfig, data, source)


def _experiment_part(args: argparse.Namespace) -> dict[str, Any]:
    """This agent's settings from an experiment file: role, platform, maneuver, ..."""
    from federation.core.keys import AgentId
    from schemas.experiment import load_experiment

    experiment = load_experiment(args.experiment)
    if not (args.lab and args.name):
        raise ConfigError(f"{args.experiment}: give --lab and --name to pick this agent's part")
    me = AgentId(args.lab, args.name)
    part = experiment.participant(me)
    if part is None:
        names = ", ".join(p.agent for p in experiment.participants)
        raise ConfigError(f"{args.experiment}: {me} does not take part (participants: {names})")
    return {
        "federation": experiment.federation,
        "role": part.role,
        "platform": part.platform,
        "follow": part.follow,
        "latency_compensation": part.latency_compensation,
        "maneuver": experiment.maneuver.model_dump(),
        "wait_start": True,
    }


def cmd_agent(args: argparse.Namespace) -> int:
    import zenoh

    from agents.kinematic import PlatformError
    from federation.runtime.agent import AgentRuntime, NameTaken
    from federation.runtime.heap import freeze_startup_heap
    from federation.runtime.session import build_config

    config = agent_config(args)
    conf = build_config(zenoh_options(args), default_mode="client")
    stop = stop_on_signals()
    session = open_interruptible(zenoh.open, conf, stop)
    if session is None:
        return 0
    with session:
        try:
            runtime = AgentRuntime(config, session)
        except PlatformError as error:
            print(f"fedlab agent: error: {error}", file=sys.stderr)
            return 1
        try:
            runtime.start()
        except NameTaken as error:
            runtime.close()
            print(f"fedlab agent: error: {error}", file=sys.stderr)
            return 2
        freeze_startup_heap()
        try:
            runtime.run(stop)
        except PlatformError as error:
            print(f"fedlab agent: error: {error}; all valves closed", file=sys.stderr)
            return 1
        finally:
            runtime.close()
    log.info("agent %s stopped", config.agent)
    return 0


def _clock_step(text: str) -> tuple[float, float]:
    at, sep, jump = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(at), float(jump)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected AT:SECONDS, e.g. 20:0.5, not {text!r}"
        ) from None


# -- demo ------------------------------------------------------------------------
def cmd_demo(args: argparse.Namespace) -> int:
    from federation.fleet.demo import run_demo

    return run_demo(
        duration=args.duration, out=args.out, delay_ms=args.delay_ms, clock_offset=args.clock_offset
    )


# -- parser ----------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fedlab",
        description="One experiment across several remote labs' floating platforms, over Zenoh.",
        formatter_class=Formatter,
        epilog="Example: fedlab demo --duration 30",
    )
    parser.add_argument("--version", action="version", version=f"fedlab {_version()}")
    parser.add_argument(
        "--log-level",
        default="info",
        choices=["debug", "info", "warning", "error"],
        help="log verbosity",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser(
        "router",
        help="run a lab's Zenoh router",
        formatter_class=Formatter,
        description="Run a lab's Zenoh router: the only fedlab process that crosses the firewall.",
        epilog=(
            "Examples:\n"
            "  fedlab router --lab kiruna -l tcp/0.0.0.0:7447\n"
            "  fedlab router --lab rome -l tcp/127.0.0.1:7448 -e tcp/kiruna.example.org:7447\n"
            "  fedlab router -c deploy/routers/kiruna.json5"
        ),
    )
    p.add_argument("--lab", help="lab name (else metadata.lab in the config file)")
    add_zenoh_flags(p)
    p.set_defaults(func=cmd_router)

    p = sub.add_parser(
        "agent",
        help="run an agent (a platform in the federation)",
        formatter_class=Formatter,
        description="Run an agent: serve sync queries, sync with peers, publish pose and status.",
        epilog=(
            "Examples:\n"
            "  fedlab agent --role leader --lab kiruna --name knatte -e tcp/127.0.0.1:7447\n"
            "  fedlab agent --role follower --lab rome --name pinocchio --follow kiruna/knatte \\\n"
            "      -e tcp/127.0.0.1:7448 --clock-offset 26.42 --status-json rome.jsonl"
        ),
    )
    p.add_argument(
        "--agent-config", type=Path, metavar="FILE", help="agent settings (TOML or JSON)"
    )
    p.add_argument(
        "--experiment",
        type=Path,
        metavar="FILE",
        help="take role, platform and maneuver from an experiment file; wait for ctl start",
    )
    p.add_argument("--federation", help="federation name (default: default)")
    p.add_argument("--lab", help="this agent's lab")
    p.add_argument("--name", help="this agent's name")
    p.add_argument(
        "--role",
        choices=["leader", "follower", "member"],
        help="leader runs the maneuver; follower tracks --follow; member only takes part",
    )
    p.add_argument("--follow", metavar="LAB/NAME", help="agent whose heading a follower tracks")
    p.add_argument(
        "--sync-with",
        action="append",
        default=[],
        metavar="LAB/NAME",
        help="sync only with these agents (default: the reference and the followed agent "
        "every --sync-period, every other agent alive every --sync-others-period)",
    )
    p.add_argument(
        "--sync-period", type=float, metavar="S", help="seconds between sync requests (0.1)"
    )
    p.add_argument(
        "--sync-others-period", type=float, metavar="S",
        help="seconds between sync requests to agents neither followed nor the reference (1)",
    )  # fmt: skip
    p.add_argument("--sync-timeout", type=float, metavar="S", help="sync reply timeout (0.5)")
    p.add_argument("--sync-window", type=float, metavar="S", help="offset averaging window (10)")
    p.add_argument(
        "--estimator",
        choices=["clockfilter", "mean", "median"],
        help="offset estimator: clockfilter (offset and drift; default) or the paper's mean/median",
    )
    p.add_argument(
        "--four-timestamps",
        action="store_const",
        const=True,
        help="also use the server's send time (for servers with slow turnaround)",
    )
    p.add_argument("--pose-rate", type=float, metavar="HZ", help="pose samples per second (20)")
    p.add_argument("--status-period", type=float, metavar="S", help="seconds between status (1)")
    p.add_argument("--clock-offset", type=float, metavar="S", help="skew this agent's clock (s)")
    p.add_argument("--clock-drift-ppm", type=float, metavar="PPM", help="clock rate error (ppm)")
    p.add_argument(
        "--platform",
        metavar="SPEC",
        help="pose source: kinematic (default), knatte, pinocchio, a platform TOML, serial:PORT",
    )
    p.add_argument("--seed", type=int, help="seed of a simulated platform's noise (0)")
    p.add_argument(
        "--no-latency-compensation",
        dest="latency_compensation",
        action="store_const",
        const=False,
        help="track the followed pose as received, without dead reckoning",
    )
    p.add_argument(
        "--clock-step",
        type=_clock_step,
        metavar="AT:S",
        help="rehearse a clock step: jump S seconds when the clock reads AT",
    )
    p.add_argument(
        "--stale-after",
        type=float,
        metavar="S",
        help="seconds without the followed pose before safe hold (0.15)",
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    p.add_argument("--status-json", type=Path, metavar="FILE", help="append status lines here")
    p.add_argument("--record", type=Path, metavar="FILE", help="record the run to an MCAP file")
    p.add_argument(
        "--wait-start",
        action="store_const",
        const=True,
        help="hold still until a start command (fedlab ctl start) instead of starting at once",
    )
    add_zenoh_flags(p)
    p.set_defaults(func=cmd_agent)

    p = sub.add_parser(
        "demo",
        help="the paper's experiment on this machine: two labs, a 40 ms link, report",
        formatter_class=Formatter,
        description=(
            "Two lab routers (kiruna listening, rome dialling it through a link emulator with\n"
            "the paper's ~40 ms one-way delay), a simulated KNATTE leading and a simulated\n"
            "PINOCCHIO following with its clock 26.42 s off; a synchronized start, the\n"
            "paper's maneuver (10 s still, 45 degrees and back in 60 s), then the report\n"
            "(report.md, summary.json, figures) beside the paper's numbers."
        ),
        epilog="Example: fedlab demo --duration 75 --out runs/demo",
    )
    p.add_argument(
        "--duration", type=float, default=75.0, metavar="S", help="seconds of run after the start"
    )
    p.add_argument(
        "--delay-ms", type=float, default=40.0, metavar="MS", help="one-way delay of the lab link"
    )
    p.add_argument("--out", type=Path, default=Path("runs/demo"), metavar="DIR", help="run folder")
    p.add_argument(
        "--clock-offset", type=float, default=26.42, metavar="S", help="follower's clock skew"
    )
    p.set_defaults(func=cmd_demo)

    for module in _COMMAND_MODULES:
        importlib.import_module(module).register(sub, Formatter, add_zenoh_flags)
    return parser


# Commands that live beside their library code: each module has
# register(subparsers, formatter_class, addadd_zenoh_flags) and sets ``func``.
_COMMAND_MODULES = (
    "federation.runtime.control",
    "federation.bridge.udp",
    "federation.runtime.monitor",
    "federation.link.emulator",
    "federation.cli.analyze",
    "federation.deploy.certs",
    "federation.report.report",
    "federation.bench",
    "agents.serial.emulator",
)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        code: int = args.func(args)
    except (ConfigError, ZenohConfigError) as error:
        print(f"fedlab {args.command}: error: {error}", file=sys.stderr)
        return 2
    return code


if __name__ == "__main__":
    sys.exit(main())

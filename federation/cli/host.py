"""``fedlab host``: run several agents in one process, on one Zenoh session.

Each agent comes from its own file (the same files as ``fedlab agent
--agent-config``); :mod:`federation.runtime.host` says what they share.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from federation.cli.agent import build_agent_config
from federation.cli.common import (
    AGENT_CPUS_HELP,
    Formatter,
    Subparsers,
    add_cpus_flag,
    add_timeout_flag,
    add_zenoh_flags,
    client_conf,
    open_session,
    stop_on_signals,
)
from schemas.config import AgentConfig, ConfigError

__all__ = ["add", "hosted_configs", "run"]

log = logging.getLogger("fedlab")


def add(sub: Subparsers) -> None:
    p = sub.add_parser(
        "host",
        help="run several agents in one process (a lab's virtual platforms)",
        formatter_class=Formatter,
        description=(
            "Run several agents in one process, on one Zenoh session and one loop thread: "
            "a pose several of them follow is read once, and agents on one clock share one "
            "sync exchange per peer. For virtual platforms (kinematic, knatte, pinocchio, a "
            "platform file); a real platform (serial:PORT) runs as its own fedlab agent."
        ),
        epilog=(
            "Examples:\n"
            "  fedlab host rome/*.toml -e tcp/127.0.0.1:7448\n"
            "  fedlab host /etc/fedlab/hosts/sim -c /etc/fedlab/hosts/sim.json5\n"
            "  fedlab host a1.toml a2.toml --experiment formation.toml --status-dir status/\n"
            "Every file holds one agent's settings, as for fedlab agent --agent-config."
        ),
    )
    p.add_argument(
        "files", nargs="+", type=Path, metavar="FILE",
        help="an agent's settings (TOML or JSON), or a folder of them",
    )  # fmt: skip
    p.add_argument(
        "--experiment",
        type=Path,
        metavar="FILE",
        help="take each agent's role, platform and maneuver from an experiment file; "
        "wait for ctl start",
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop every agent after S s")
    p.add_argument(
        "--status-dir",
        type=Path,
        metavar="DIR",
        help="append each agent's status lines to DIR/<lab>-<name>.jsonl (unless its "
        "file names a status_json)",
    )
    p.add_argument(
        "--group",
        type=_group,
        default=1,
        metavar="N",
        help="agents that tick on one wake-up: fewer wake-ups cost less CPU, but each "
        "holds the interpreter longer (docs/scale.md)",
    )
    add_cpus_flag(p, AGENT_CPUS_HELP)
    add_zenoh_flags(p)
    add_timeout_flag(p, service=True)
    p.set_defaults(func=run)


def _group(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"a number of agents, at least 1, not {text!r}")
    return value


def hosted_configs(args: argparse.Namespace) -> list[tuple[str, AgentConfig]]:
    """Each file's agent (its part in ``--experiment`` too, ``--duration`` and
    ``--status-dir`` over it), with the file's name; refused (ConfigError naming the
    file and field) if one process must not host them
    (:func:`federation.runtime.host.check_hosted`)."""
    from federation.runtime.host import check_hosted

    hosted = []
    for file in _agent_files(args.files):
        flags = {} if args.duration is None else {"duration": args.duration}
        config = build_agent_config(file, args.experiment, flags)
        if args.status_dir is not None and config.status_json is None:
            stem = f"{config.lab}-{config.name}"
            config = config.model_copy(update={"status_json": args.status_dir / f"{stem}.jsonl"})
        hosted.append((str(file), config))
    check_hosted(hosted)
    return hosted


def _agent_files(paths: list[Path]) -> list[Path]:
    """The files given, a folder standing for its ``*.toml`` and ``*.json`` files."""
    files = []
    for path in paths:
        if path.is_dir():
            found = sorted([*path.glob("*.toml"), *path.glob("*.json")])
            if not found:
                raise ConfigError(f"{path}: a folder without agent files (*.toml, *.json)")
            files += found
        else:
            files.append(path)
    return files


def _check_identity(args: argparse.Namespace, hosted: list[tuple[str, AgentConfig]]) -> None:
    """The identity the Zenoh config proves (certificate CN, user name) may speak for
    every hosted agent: the lab router drops what it sends for any other (an
    IdentityError: exit 2)."""
    from federation.runtime.identity import check_hosted_identity
    from federation.runtime.router import refuse_reachable_agent

    conf, source = client_conf(args)
    check_hosted_identity(conf, [config.agent for _, config in hosted], source)
    refuse_reachable_agent(conf, source)


def run(args: argparse.Namespace) -> int:
    from agents.platform import PlatformError
    from federation.runtime.agent import NameTaken
    from federation.runtime.heap import freeze_startup_heap
    from federation.runtime.host import host

    hosted = hosted_configs(args)
    _check_identity(args, hosted)
    if args.cpus is not None:
        from federation.runtime.cpus import pin_process

        pin_process(args.cpus, "--cpus")  # before the session: Zenoh's threads inherit it
    stop = stop_on_signals()
    session = open_session(args, stop)
    if session is None:
        return 0
    configs = [config for _, config in hosted]
    names = ", ".join(str(c.agent) for c in configs)
    with session:
        try:
            host(configs, session, stop, group=args.group, on_started=freeze_startup_heap)
        except NameTaken as error:
            print(f"fedlab host: error: {error}; every agent closed", file=sys.stderr)
            return 2
        except PlatformError as error:
            print(f"fedlab host: error: {error}; every agent's valves closed", file=sys.stderr)
            return 1
    log.info("host stopped: %s", names)
    return 0

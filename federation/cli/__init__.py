"""``fedlab`` command line: parse, call the library, turn errors into clear messages.

One module per command in this package, each with ``add(sub)`` (its parser, help
with an example, ``func=run``) and ``run(args) -> int`` (parse, call the library,
print, exit code); :data:`COMMANDS` lists them in the order help shows them. What
they share (Zenoh's usual flags -m/-e/-l/-c/--cfg, signal handling, opening a
session, argument types) is in :mod:`federation.cli.common`. Only this package
imports argparse.

Exit codes: 0 done; 1 failed at run time (a network failure, an agent that did
not confirm); 2 bad usage or configuration.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from types import ModuleType

from federation.cli import (
    agent,
    analyze,
    bench,
    bridge,
    certs,
    collect,
    ctl,
    demo,
    deploy,
    emulate_device,
    foxglove,
    link,
    monitor,
    report,
    router,
    schemas,
)
from federation.cli.common import Formatter, signal_handlers_kept
from federation.runtime.session import ConnectError, ZenohConfigError
from schemas.config import ConfigError

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS: tuple[ModuleType, ...] = (
    router,
    agent,
    demo,
    ctl,
    monitor,
    foxglove,
    collect,
    link,
    bridge,
    emulate_device,
    report,
    analyze,
    bench,
    certs,
    deploy,
    schemas,
)
"""The command modules, each with ``add(sub)`` and ``run(args)``."""


def _version() -> str:
    try:
        return version("fedlab")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The ``fedlab`` parser with every command of :data:`COMMANDS`."""
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
    for command in COMMANDS:
        command.add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fedlab`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        with signal_handlers_kept():
            code: int = args.func(args)
    except (ConfigError, ZenohConfigError) as error:
        print(f"fedlab {args.command}: error: {error}", file=sys.stderr)
        return 2
    except ConnectError as error:
        print(f"fedlab {args.command}: error: {error}", file=sys.stderr)
        return 1
    return code


if __name__ == "__main__":
    sys.exit(main())

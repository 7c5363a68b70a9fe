"""``fedlab`` command line: parse, call the library, turn errors into clear messages.

One module per command in this package, each with ``add(sub)`` (its parser, help
with an example, ``func=run``) and ``run(args) -> int`` (parse, call the library,
print, exit code); :data:`COMMANDS` names them in the order help shows them. A
command line imports only the module of the command it runs (``fedlab router``
does not load the Kalman filter or the report's plotting), so a router or
``fedlab ctl`` starts in about half the time; ``fedlab --help`` imports them all. What
they share (Zenoh's usual flags -m/-e/-l/-c/--cfg, signal handling, opening a
session, argument types) is in :mod:`federation.cli.common`. Only this package
imports argparse.

Exit codes: 0 done; 1 failed at run time (a network failure, an agent that did
not confirm); 2 bad usage or configuration.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version
from types import ModuleType

from federation.cli.common import Formatter, exit_on_sigterm, signal_handlers_kept
from federation.runtime.session import ConnectError, ZenohConfigError
from schemas.config import ConfigError

__all__ = ["COMMANDS", "build_parser", "command_module", "main"]

COMMANDS: tuple[str, ...] = (
    "router",
    "agent",
    "host",
    "demo",
    "ctl",
    "monitor",
    "foxglove",
    "collect",
    "link",
    "bridge",
    "emulate-device",
    "report",
    "merge",
    "replay",
    "analyze",
    "bench",
    "certs",
    "deploy",
    "schemas",
)
"""The commands; each is the module ``federation.cli.<name>`` (``-`` as ``_``) with
``add(sub)`` and ``run(args)``."""


def command_module(name: str) -> ModuleType:
    """The module of command ``name``, imported now."""
    return importlib.import_module(f"federation.cli.{name.replace('-', '_')}")


def chosen_command(argv: Sequence[str]) -> str | None:
    """The command ``argv`` runs, if it names one of :data:`COMMANDS` (only
    ``fedlab``'s own options may come before it)."""
    words = iter(argv)
    for word in words:
        if word == "--log-level":
            next(words, None)
        elif not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def _version() -> str:
    try:
        return version("fedlab")
    except PackageNotFoundError:
        return "unknown"


def build_parser(commands: Sequence[str] = COMMANDS) -> argparse.ArgumentParser:
    """The ``fedlab`` parser with ``commands`` (default: every one of :data:`COMMANDS`)."""
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
    for command in commands:
        command_module(command).add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fedlab`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    command = chosen_command(argv)
    parser = build_parser(COMMANDS if command is None else (command,))
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level.upper(),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        with signal_handlers_kept():
            exit_on_sigterm()
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

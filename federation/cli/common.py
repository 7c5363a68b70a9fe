"""What every ``fedlab`` command shares: the help formatter, Zenoh's usual flags,
opening a session that a signal can interrupt, stopping on signals, and argument
types. Each command module in this package parses with these and calls the library.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

from federation.runtime.session import ZenohConfigError
from schemas.config import ZenohOptions, validate

__all__ = [
    "Formatter",
    "Subparsers",
    "add_zenoh_flags",
    "nonnegative",
    "open_interruptible",
    "positive",
    "probability",
    "stop_on_signals",
    "zenoh_options",
]

log = logging.getLogger("fedlab")

Subparsers = argparse._SubParsersAction


class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    pass


def add_zenoh_flags(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("zenoh")
    group.add_argument("-m", "--mode", choices=["client", "peer", "router"], help="session mode")
    group.add_argument(
        "-e",
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to dial, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    group.add_argument(
        "-l",
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable)",
    )
    group.add_argument("-c", "--config", type=Path, metavar="FILE", help="Zenoh json5 config file")
    group.add_argument(
        "--cfg",
        action="append",
        default=[],
        metavar="KEY:VALUE",
        help="extra Zenoh setting, VALUE as json5 (repeatable)",
    )


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    data = {k: getattr(args, k) for k in ("mode", "connect", "listen", "config", "cfg")}
    return validate(ZenohOptions, data, "command line")


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM: both stop cleanly with exit code 0."""
    stop = threading.Event()

    def handler(signum: int, frame: FrameType | None) -> None:
        log.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def open_interruptible(opener: Callable[[Any], Any], conf: Any, stop: threading.Event) -> Any:
    """Open a session in a helper thread, so a signal can stop an agent still waiting for its
    router (zenoh.open retries a missing router forever and does not return to Python)."""
    result: dict[str, Any] = {}

    def target() -> None:
        try:
            result["session"] = opener(conf)
        except Exception as error:
            result["error"] = error

    thread = threading.Thread(target=target, name="zenoh-open", daemon=True)
    thread.start()
    started = time.monotonic()
    next_note = started + 2.0
    while thread.is_alive() and not stop.is_set():
        thread.join(0.1)
        if time.monotonic() >= next_note:
            log.info("waiting for the router (%.0f s)...", time.monotonic() - started)
            next_note += 10.0
    if "error" in result:
        raise ZenohConfigError(f"cannot open a Zenoh session: {result['error']}")
    if stop.is_set() and "session" not in result:
        log.info("stopped before the router was reached")
        return None
    return result["session"]


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, not {text!r}")
    return value


def positive(text: str) -> float:
    """Argument type: a finite number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, not {text!r}")
    return value


def nonnegative(text: str) -> float:
    """Argument type: a finite number >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, not {text!r}")
    return value


def probability(text: str) -> float:
    """Argument type: a number in [0, 1]."""
    value = nonnegative(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], not {text!r}")
    return value

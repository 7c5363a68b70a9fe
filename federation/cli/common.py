"""What every ``fedlab`` command shares: the help formatter, Zenoh's usual flags,
opening a session that a signal can interrupt, stopping on signals, and argument
types. Each command module in this package parses with these and calls the library.

The one place for each: Zenoh flags (:func:`add_zenoh_flags`, :func:`zenoh_options`),
signal handling (:func:`stop_on_signals`, :func:`signal_handlers_kept`) and opening a
session (:func:`open_session`, :func:`open_interruptible`).
"""

from __future__ import annotations

import argparse
import faulthandler
import logging
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, TypeAlias

from federation.core import keys
from federation.runtime.session import ConnectError
from federation.runtime.signals import stop_event
from schemas.config import ZenohOptions, validate

__all__ = [
    "Formatter",
    "Subparsers",
    "add_federation_flag",
    "add_timeout_flag",
    "add_zenoh_flags",
    "agent_id",
    "count",
    "exit_on_sigterm",
    "federation_name",
    "integer_in",
    "nonnegative",
    "open_interruptible",
    "open_session",
    "positive",
    "probability",
    "run_id",
    "signal_handlers_kept",
    "stop_on_signals",
    "zenoh_options",
]

log = logging.getLogger("fedlab")

if TYPE_CHECKING:
    Subparsers: TypeAlias = argparse._SubParsersAction[argparse.ArgumentParser]
else:  # not subscriptable at run time
    Subparsers = argparse._SubParsersAction
"""What ``add_subparsers()`` returns: each command module's ``add(sub)`` adds to it."""

# SIGHUP too: an agent started from a terminal or an SSH session that drops must close
# its platform's valves, not leave them to the device's failsafe.
_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
# A clean stop takes well under this; a process still stopping after it writes every
# thread's stack to stderr, so a stop that hangs says where (and a supervisor's
# SIGKILL that follows does not leave that unknown).
STOP_REPORT_AFTER = 4.0


class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Descriptions and epilogs as written (line breaks kept), each option's default shown
    once: appended as ``(default: X)`` unless its help already says its default, and
    never for an option without one (None, an empty list), nor for an on/off flag, whose
    default is the state its name does not ask for (``--no-icmp``: ICMP is on)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if not _shows_default(action) or "default" in text.lower():
            return text
        return f"{text} (default: %(default)s)"


def _shows_default(action: argparse.Action) -> bool:
    """Whether ``action``'s default is worth a ``(default: X)`` in the help: a value the
    option takes when not given, not None, an empty list, nor an on/off flag's state."""
    default = action.default
    if default is None or default is argparse.SUPPRESS or default == []:
        return False
    if action.nargs == 0:  # a flag: store_true/false/const, count, help, version
        return False
    return bool(action.option_strings) or action.nargs in (argparse.OPTIONAL, "*")


def add_zenoh_flags(parser: argparse.ArgumentParser) -> None:
    """Zenoh's usual flags, as its own examples take them: -m, -e, -l, -c, --cfg."""
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


def add_timeout_flag(parser: argparse.ArgumentParser, service: bool = False) -> None:
    """``--timeout S``: give up on an unreachable router after S seconds. A ``service``
    (a long-running command: agent, host, bridge, view) keeps waiting for its router
    unless given one, so that a lab's services may start before its router does."""
    from federation.runtime.session import DEFAULT_TIMEOUT

    if service:
        parser.add_argument(
            "--timeout",
            type=positive,
            default=None,
            metavar="S",
            help="give up on an unreachable router after S seconds, naming the endpoint "
            "and why (default: keep waiting for it, saying so every 10 s)",
        )
        return
    parser.add_argument(
        "--timeout",
        type=positive,
        default=DEFAULT_TIMEOUT,
        metavar="S",
        help="give up on an unreachable router after S seconds (names the endpoint and why)",
    )


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """The Zenoh flags of parsed ``args``, validated (a ConfigError names the flag)."""
    data = {k: getattr(args, k) for k in ("mode", "connect", "listen", "config", "cfg")}
    return validate(ZenohOptions, data, "command line")


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT, SIGTERM, SIGHUP or SIGQUIT: each stops cleanly, exit code 0.
    A process still stopping :data:`STOP_REPORT_AFTER` seconds later dumps its threads'
    stacks to stderr. The handler takes no lock (:mod:`federation.runtime.signals`)."""
    return stop_event(_SIGNALS, report_after=STOP_REPORT_AFTER)


def exit_on_sigterm() -> None:
    """Make SIGTERM unwind the command like Ctrl-C does, exiting with 143 (128 + 15).

    Python's default for SIGTERM ends the process at once: no ``finally``, no
    ``with`` exit. A command that runs child processes (``fedlab demo``, the
    benchmarks: routers and agents in a :class:`~federation.fleet.launch.Fleet`)
    then left them running, routers for ever. Raised as ``SystemExit`` instead, the
    fleet stops its children by pid on the way out; a second SIGTERM meanwhile is
    ignored, so that stopping them is not cut short (each stop is bounded: SIGKILL
    after a grace period). Commands that stop cleanly on their own
    (:func:`stop_on_signals`) replace this handler."""

    def handler(signum: int, frame: FrameType | None) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        log.warning("received SIGTERM: stopping what this command started")
        raise SystemExit(128 + signal.SIGTERM)

    signal.signal(signal.SIGTERM, handler)


@contextmanager
def signal_handlers_kept() -> Iterator[None]:
    """Put back the SIGINT and SIGTERM handlers found on entry: :func:`stop_on_signals`
    replaces them, and ``main()`` may run inside another program or a test."""
    previous = {sig: signal.getsignal(sig) for sig in _SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        # The command has stopped: a stack dump armed by its signal is not for what runs
        # next in this process (a test, the program that called main()).
        faulthandler.cancel_dump_traceback_later()


def open_interruptible(
    opener: Callable[[Any], Any],
    conf: Any,
    stop: threading.Event,
    timeout: float | None = None,
    source: str = "the Zenoh config",
) -> Any:
    """Open a session in a helper thread, so a signal can stop an agent still waiting for its
    router (zenoh.open retries a missing router forever and does not return to Python).

    While it waits, it says so every 10 s (the first time after 2 s) with why, as a probe
    of each endpoint finds it (:func:`~federation.runtime.session.diagnose`): connection
    refused, or which certificate or login a TLS router refuses, naming the files to
    check (``source``: where ``conf`` came from); an authentication failure is logged as
    a warning as soon as a probe finds it. Zenoh itself says nothing while it retries.

    Returns the session, or None when ``stop`` was set first; raises
    :class:`~federation.runtime.session.ConnectError` when Zenoh cannot open one (with
    ``timeout``: within it), naming each endpoint and why it failed.
    """
    from federation.runtime.session import connect_error, endpoints

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
    # Zenoh gives up by itself after the timeout; this is the backstop.
    deadline = math.inf if timeout is None else started + timeout + 2.0
    where = ", ".join(endpoints(conf)) or "no endpoint"
    why = _WhyWaiting(conf, source) if timeout is None else None
    while thread.is_alive() and not stop.is_set():
        thread.join(0.1)
        now = time.monotonic()
        if now >= deadline:
            raise connect_error(conf, "no answer", timeout or 0.0, source)
        if why is not None:
            why.poll(now - started)
        if now >= next_note:
            reason = f": {why.reason}" if why is not None and why.reason else ""
            log.info("waiting for the router at %s (%.0f s)...%s", where, now - started, reason)
            next_note += 10.0
    if "error" in result:
        if timeout is not None:
            raise connect_error(conf, result["error"], timeout, source)
        raise ConnectError(f"cannot open a Zenoh session ({where}): {result['error']}")
    if stop.is_set() and "session" not in result:
        log.info("stopped before the router was reached")
        return None
    return result["session"]


class _WhyWaiting:
    """Why a session does not open yet: each endpoint probed on a thread of its own
    (:func:`~federation.runtime.session.examine`, a few seconds at most), 1 s after the
    first attempt and every 10 s after; a new authentication failure is logged at once.

    A login refused after TLS (``password``, ``session``) cannot be told from a router
    that came up a moment ago, before Zenoh's next try (it retries 1 s, then 2 s, then
    every 4 s): it is said only once the session is still not open :data:`SETTLED` s
    after the probe that found it."""

    FIRST, PERIOD = 1.0, 10.0
    SETTLED = 4.5  # s: Zenoh's longest wait between tries, and a margin
    AFTER_TLS = ("password", "session")

    def __init__(self, conf: Any, source: str):
        from federation.runtime.session import endpoints
        from federation.runtime.tlsprobe import client_tls

        self.endpoints = endpoints(conf)
        self.tls = client_tls(conf, source)
        self.found: list[tuple[str, Any]] = []  # (why, AuthFailure or None) per endpoint
        self.found_at = 0.0
        self.warned: set[str] = set()
        self.reason = ""
        self.next_probe = self.FIRST
        self.waited = 0.0
        self.thread: threading.Thread | None = None

    def _probe(self) -> None:
        from federation.runtime.session import examine

        at = self.waited
        found = [examine(e, 2.0, self.tls) for e in self.endpoints]
        self.found, self.found_at = found, at

    def _said(self, waited: float) -> list[tuple[str, Any]]:
        """The findings as they may be said now (a refusal after TLS only once settled)."""
        settled = waited >= self.found_at + self.SETTLED
        return [
            ("TLS accepted, no session yet", None)
            if failure is not None and failure.kind in self.AFTER_TLS and not settled
            else (why, failure)
            for why, failure in self.found
        ]

    def poll(self, waited: float) -> None:
        """Start a probe when one is due; log an authentication failure it found."""
        self.waited = waited
        said = self._said(waited)
        for _, failure in said:
            if failure is not None and failure.message not in self.warned:
                self.warned.add(failure.message)
                log.warning("no session with the router yet: %s (still trying)", failure.message)
        if len(self.endpoints) == 1:
            self.reason = "; ".join(why for why, _ in said)
        else:
            pairs = zip(self.endpoints, said, strict=False)  # said: empty before a probe
            self.reason = "; ".join(f"{e}: {why}" for e, (why, _) in pairs)
        if waited >= self.next_probe and (self.thread is None or not self.thread.is_alive()):
            self.next_probe = waited + self.PERIOD
            self.thread = threading.Thread(target=self._probe, name="why-waiting", daemon=True)
            self.thread.start()


def open_session(
    args: argparse.Namespace, stop: threading.Event, default_mode: str = "client"
) -> Any:
    """A Zenoh session from the command's Zenoh flags (see :func:`open_interruptible`);
    None when ``stop`` was set before the router answered. A command with
    ``--timeout`` (:func:`add_timeout_flag`) gives up after it."""
    import zenoh

    from federation.runtime.session import build_config, fail_fast

    options = zenoh_options(args)
    conf = build_config(options, default_mode=default_mode)
    timeout: float | None = getattr(args, "timeout", None)
    if timeout is not None:
        fail_fast(conf, timeout)
    source = str(options.config) if options.config else "the Zenoh flags"
    return open_interruptible(zenoh.open, conf, stop, timeout, source)


def federation_name(text: str) -> str:
    """Argument type: a federation name (lowercase letters, digits, ``-`` and ``_``)."""
    try:
        return keys.validate_name(text, "federation name")
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_federation_flag(parser: argparse.ArgumentParser, help: str = "federation name") -> None:
    """``--federation NAME``, a checked federation name (default: the default federation)."""
    parser.add_argument(
        "--federation", type=federation_name, default=keys.DEFAULT_FEDERATION, metavar="NAME",
        help=help,
    )  # fmt: skip


def cpus(text: str) -> frozenset[int]:
    """Argument type: a list of cores (``0``, ``2-3``, ``0,2-3``)."""
    from federation.runtime.cpus import parse_cpus

    try:
        return parse_cpus(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


AGENT_CPUS_HELP = (
    "run on these cores only, e.g. 1-3 (Linux): on a host shared with the lab's router, "
    "the cores it does not use (fedlab router --cpus; docs/deploy.md)"
)
"""``--cpus`` of the commands that run agents (``fedlab agent``, ``fedlab host``)."""


def client_conf(args: argparse.Namespace) -> tuple[Any, str]:
    """The Zenoh client config the command's flags give, and how errors name it (the
    config file, or "Zenoh flags"), for the identity checks before any session."""
    from federation.runtime.session import build_config

    options = zenoh_options(args)
    source = str(options.config) if options.config else "Zenoh flags"
    return build_config(options, default_mode="client"), source


def check_agent_identity(args: argparse.Namespace, agent: object) -> None:
    """Identity = name: the certificate CN or user name the command's Zenoh config proves
    must be ``agent``'s lab/name (an IdentityError, a ConfigError: exit 2), checked before
    any session. The lab router lets an identity write only under its own keys: under
    another name, what the agent sends would be dropped, silently."""
    from federation.runtime.identity import check_identity
    from federation.runtime.router import refuse_reachable_agent

    conf, source = client_conf(args)
    check_identity(conf, str(agent), source)
    refuse_reachable_agent(conf, source)


def add_cpus_flag(parser: argparse.ArgumentParser, help: str) -> None:
    """``--cpus LIST``: the cores the process (every thread of it) runs on."""
    parser.add_argument("--cpus", type=cpus, metavar="LIST", help=help)


def run_id(text: str) -> str:
    """Argument type: a run's name, safe as a folder name."""
    from federation.core.chunking import RequestError, safe_name

    try:
        return safe_name(text, "run id")
    except RequestError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def agent_id(text: str) -> keys.AgentId:
    """Argument type: an agent's address, ``LAB/NAME``."""
    try:
        return keys.AgentId.parse(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, not {text!r}")
    return value


def count(text: str) -> int:
    """Argument type: a whole number of at least 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"at least 1, not {text!r}")
    return n


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


def integer_in(low: int, high: int, what: str) -> Callable[[str], int]:
    """Argument type: a whole number from ``low`` to ``high``, a ``what`` (for messages)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{what} is {low} to {high}, not {value}")
        return value

    return parse

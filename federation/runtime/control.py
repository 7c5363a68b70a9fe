"""``fedlab ctl start|freeze|resume|abort``: execution control over the federation.

``start`` syncs with the reference agent (the experiment's leader) exactly as
agents do, then announces a start at a reference time ``--in`` seconds ahead;
every agent begins when its own synchronized clock reaches that instant. The
other commands act on receipt. Each command is published a few times with the
same sequence number (agents ignore repeats) and ctl waits, bounded, until every
expected agent reports the new mode.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from federation.core import keys
from federation.core.clockfilter import ClockFilter
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.clock import ExecClock
from schemas.config import ConfigError
from schemas.messages import Command

__all__ = ["register"]

_EXPECTED_MODE = {
    "start": {"armed", "running"},
    "freeze": {"frozen"},
    "resume": {"running"},
    "abort": {"aborted"},
}


class Federation:
    """What ctl sees of a federation: every agent's latest status."""

    def __init__(self, session: Any, federation: str):
        import zenoh

        self.session = session
        self.federation = federation
        self.status: dict[str, dict[str, Any]] = {}
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(
            keys.all_of(federation, "status"),
            zenoh.handlers.Callback(self._on_status, indirect=False),
        )

    def _on_status(self, sample: Any) -> None:
        try:
            status = json.loads(sample.payload.to_bytes())
            with self._lock:
                self.status[status["agent"]] = status
        except (ValueError, KeyError, TypeError):
            pass  # a malformed status is the monitor's business, not ctl's

    def snapshot(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return dict(self.status)

    def close(self) -> None:
        self._sub.undeclare()


def reference_now(session: Any, federation: str, reference: AgentId, clock: ExecClock) -> float:
    """The reference agent's clock now, from a burst of sync exchanges (best of 20)."""
    import zenoh

    client = SyncClient(ClockFilter(), timeout=1.0)
    key = keys.agent_key(federation, reference, "sync")
    done = threading.Event()

    def on_reply(reply: Any) -> None:
        t3 = clock.now()
        if reply.ok is not None:
            client.receive(reply.ok.payload.to_bytes(), t3)
        done.set()

    for _ in range(20):
        done.clear()
        session.get(
            key,
            zenoh.handlers.Callback(on_reply, indirect=False),
            payload=client.request(clock.now()),
            timeout=1.0,
            consolidation=zenoh.ConsolidationMode.NONE,
        )
        done.wait(1.0)
        time.sleep(0.02)
    t = clock.now()
    offset = client.offset_at(t)
    if offset is None:
        raise ConfigError(f"reference agent {reference} did not answer sync queries on {key}")
    return t + offset


def send(
    session: Any,
    federation: str,
    command: Command,
    expected: set[str],
    fed: Federation,
    timeout: float,
    progress: Callable[[str], None],
) -> dict[str, str]:
    """Publish ``command`` (three times) and wait until ``expected`` agents report the mode."""
    payload = command.model_dump_json()
    key = keys.control_key(federation)
    for _ in range(3):
        session.put(key, payload)
        time.sleep(0.05)
    want = _EXPECTED_MODE[command.command]
    deadline = time.monotonic() + timeout
    while True:
        modes = {a: s.get("mode", "?") for a, s in fed.snapshot().items()}
        pending = {a for a in expected if modes.get(a) not in want}
        if not pending or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    if pending:
        progress(f"no confirmation within {timeout:.0f} s from: {', '.join(sorted(pending))}")
    return {a: modes.get(a, "absent") for a in sorted(expected | set(modes))}


def cmd_ctl(args: argparse.Namespace) -> int:
    import zenoh
    from rich.console import Console
    from rich.table import Table

    from federation.cli.common import open_interruptible, stop_on_signals, zenoh_options
    from federation.runtime.session import build_config
    from schemas.experiment import load_experiment

    console = Console()
    experiment = load_experiment(args.experiment) if args.experiment else None
    federation = experiment.federation if experiment else args.federation
    keys.validate_name(federation, "federation name")
    conf = build_config(zenoh_options(args), default_mode="client")
    session = open_interruptible(zenoh.open, conf, stop_on_signals())
    if session is None:
        return 0
    with session:
        fed = Federation(session, federation)
        try:
            time.sleep(args.discover)  # statuses arrive once a second
            seen = fed.snapshot()
            expected = {p.agent for p in experiment.participants} if experiment else set(seen)
            if not expected:
                raise ConfigError(f"no agent found in federation {federation!r}")
            at = None
            maneuver = experiment.maneuver if experiment else None
            reference = _reference(args, experiment, seen)
            clock = ExecClock()
            ref_now = reference_now(session, federation, reference, clock)
            ref_offset = ref_now - clock.now()
            if args.action == "start":
                delay = args.start_in if args.start_in is not None else (
                    experiment.start_delay if experiment else 3.0
                )  # fmt: skip
                at = ref_now + delay
                console.print(f"start at reference time {at:.3f} s ({reference}'s clock)")
            command = Command(
                command=args.action,
                at=at,
                seq=time.time_ns() // 1_000_000,
                issued_at=clock.now() + ref_offset,
                issuer="ctl",
                experiment=experiment.name if experiment else None,
                maneuver=maneuver,
            )
            sent = time.monotonic()
            modes = send(session, federation, command, expected, fed, args.wait, console.print)
            table = Table(title=f"fedlab ctl {args.action} ({time.monotonic() - sent:.2f} s)")
            table.add_column("agent")
            table.add_column("mode")
            for agent, mode in modes.items():
                table.add_row(agent, mode)
            console.print(table)
            ok = all(modes.get(a) in _EXPECTED_MODE[args.action] for a in expected)
            return 0 if ok else 1
        finally:
            fed.close()


def _reference(
    args: argparse.Namespace, experiment: Any, seen: dict[str, dict[str, Any]]
) -> AgentId:
    if args.reference:
        return AgentId.parse(args.reference)
    if experiment is not None:
        leader: AgentId = experiment.leader
        return leader
    leaders = sorted(a for a, s in seen.items() if s.get("role") == "leader")
    if len(leaders) != 1:
        raise ConfigError(
            f"found {len(leaders)} leaders ({', '.join(leaders) or 'none'}): "
            "name the reference with --reference LAB/NAME or --experiment FILE"
        )
    return AgentId.parse(leaders[0])


def register(
    sub: Any,
    formatter: type[argparse.HelpFormatter],
    add_zenoh_flags: Callable[[argparse.ArgumentParser], None],
) -> None:
    p = sub.add_parser(
        "ctl",
        help="start, freeze, resume or abort a run across the federation",
        formatter_class=formatter,
        description=(__doc__ or "").split("\n\n")[1],
        epilog=(
            "Examples:\n"
            "  fedlab ctl start --experiment deploy/experiments/attitude-tracking.toml \\\n"
            "      -e tcp/127.0.0.1:7447\n"
            "  fedlab ctl abort -e tcp/127.0.0.1:7447"
        ),
    )
    p.add_argument("action", choices=["start", "freeze", "resume", "abort"])
    p.add_argument("--experiment", type=Path, metavar="FILE", help="experiment file (TOML)")
    p.add_argument("--federation", default=keys.DEFAULT_FEDERATION, help="federation name")
    p.add_argument("--reference", metavar="LAB/NAME", help="agent whose clock is reference time")
    p.add_argument(
        "--in", dest="start_in", type=float, metavar="S",
        help="start this many seconds ahead (default: the experiment's start_delay, else 3)",
    )  # fmt: skip
    p.add_argument("--wait", type=float, default=5.0, metavar="S", help="confirmation timeout")
    p.add_argument(
        "--discover", type=float, default=1.5, metavar="S", help="seconds to collect statuses"
    )
    add_zenoh_flags(p)
    p.set_defaults(func=cmd_ctl)

"""Execution control over a federation: start, freeze, resume or abort a run.

``start`` syncs with the reference agent (the experiment's leader) exactly as
agents do, then announces a start at a reference time some seconds ahead;
every agent begins when its own synchronized clock reaches that instant. The
other commands act on receipt. Each command is published a few times with the
same sequence number (agents ignore repeats) and :func:`issue` waits, bounded,
until every expected agent reports the new mode.

:func:`issue` does it all on an open session and returns a :class:`ControlResult`;
``fedlab ctl`` (:mod:`federation.cli.ctl`) parses, calls it and prints the table.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from federation.core import keys
from federation.core.clockfilter import ClockFilter
from federation.core.keys import AgentId
from federation.core.sync import SyncClient
from federation.runtime.clock import ExecClock
from federation.runtime.session import ConnectError
from schemas.config import ConfigError
from schemas.experiment import ExperimentConfig
from schemas.messages import Command

__all__ = [
    "ACTIONS",
    "DEFAULT_START_IN",
    "EXPECTED_MODE",
    "Action",
    "ControlResult",
    "Federation",
    "choose_reference",
    "issue",
    "reference_now",
    "send",
]

Action = Literal["start", "freeze", "resume", "abort"]

EXPECTED_MODE: dict[str, frozenset[str]] = {
    "start": frozenset({"armed", "running"}),
    "freeze": frozenset({"frozen"}),
    "resume": frozenset({"running"}),
    "abort": frozenset({"aborted"}),
}
"""The modes an agent reports once it has taken each command."""
ACTIONS: tuple[Action, ...] = ("start", "freeze", "resume", "abort")
DEFAULT_START_IN = 3.0
"""s between the announcement and a start, without an experiment's ``start_delay``."""


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


@dataclass(frozen=True)
class ControlResult:
    """A command as sent and the federation's answer to it."""

    command: Command
    reference: AgentId
    expected: frozenset[str]
    """Agents that had to confirm: the experiment's participants, else every agent seen."""
    modes: dict[str, str]
    """Every expected or seen agent (sorted) and its last reported mode; ``absent``: none."""
    elapsed: float
    """s from the first publication until all confirmed or the wait ran out."""

    @property
    def pending(self) -> list[str]:
        """Expected agents that did not report the command's mode in time."""
        want = EXPECTED_MODE[self.command.command]
        return sorted(a for a in self.expected if self.modes.get(a) not in want)

    @property
    def ok(self) -> bool:
        """Every expected agent confirmed."""
        return not self.pending


def reference_now(session: Any, federation: str, reference: AgentId, clock: ExecClock) -> float:
    """The reference agent's clock now, from a burst of sync exchanges (best of 20).

    Raises :class:`~federation.runtime.session.ConnectError` when it never answers.
    """
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
        raise ConnectError(f"reference agent {reference} did not answer sync queries on {key}")
    return t + offset


def send(
    session: Any,
    federation: str,
    command: Command,
    expected: set[str] | frozenset[str],
    fed: Federation,
    timeout: float,
    progress: Callable[[str], None],
) -> dict[str, str]:
    """Publish ``command`` (three times) and wait until ``expected`` agents report the mode.

    Returns every expected or seen agent's last mode (``absent`` for none), sorted.
    """
    payload = command.model_dump_json()
    key = keys.control_key(federation)
    for _ in range(3):
        session.put(key, payload)
        time.sleep(0.05)
    want = EXPECTED_MODE[command.command]
    deadline = time.monotonic() + timeout
    while True:
        modes = {a: s.get("mode", "?") for a, s in fed.snapshot().items()}
        pending = {a for a in expected if modes.get(a) not in want}
        if not pending or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    if pending:
        progress(f"no confirmation within {timeout:.0f} s from: {', '.join(sorted(pending))}")
    return {a: modes.get(a, "absent") for a in sorted(set(expected) | set(modes))}


def choose_reference(
    reference: AgentId | None,
    experiment: ExperimentConfig | None,
    seen: dict[str, dict[str, Any]],
) -> AgentId:
    """The agent whose clock is reference time: ``reference`` if given, else the
    experiment's leader, else the one agent seen with role ``leader``.

    Raises :class:`ConfigError` when none or several leaders are seen.
    """
    if reference is not None:
        return reference
    if experiment is not None:
        return experiment.leader
    leaders = sorted(a for a, s in seen.items() if s.get("role") == "leader")
    if len(leaders) != 1:
        raise ConfigError(
            f"found {len(leaders)} leaders ({', '.join(leaders) or 'none'}): "
            "name the reference with --reference LAB/NAME or --experiment FILE"
        )
    return AgentId.parse(leaders[0])


def issue(
    session: Any,
    action: Action,
    *,
    federation: str = keys.DEFAULT_FEDERATION,
    experiment: ExperimentConfig | None = None,
    reference: AgentId | None = None,
    start_in: float | None = None,
    wait: float = 5.0,
    discover: float = 1.5,
    progress: Callable[[str], None] = lambda text: None,
) -> ControlResult:
    r"""Send ``action`` to every agent of a federation and collect their confirmations.

    Parameters
    ----------
    session
        An open Zenoh session.
    action
        ``start``, ``freeze``, ``resume`` or ``abort``.
    federation
        Federation name; an ``experiment``'s own name wins.
    experiment
        The run: its participants must confirm, its leader is the reference, its
        maneuver and ``start_delay`` go with a start.
    reference
        Agent whose clock is reference time (default: see :func:`choose_reference`).
    start_in
        s between now (reference time) and the start; default the experiment's
        ``start_delay``, else :data:`DEFAULT_START_IN`.
    wait
        s to wait for confirmations.
    discover
        s to collect statuses first (agents publish one a second).
    progress
        Called with a line of text on the way (start time, missing confirmations).

    The start instant, on the reference clock :math:`t_r`, is

    .. math:: t_{start} = t_r(now) + \Delta_{in},
              \qquad t_r(now) = t_{ctl}(now) + \hat\theta

    with :math:`\hat\theta` the offset estimated by a burst of sync exchanges.

    Raises
    ------
    ConnectError
        No agent seen in the federation, or the reference does not answer.
    ConfigError
        No single leader to take as the reference.
    """
    if action not in EXPECTED_MODE:
        raise ValueError(f"unknown action {action!r}: expected one of {', '.join(ACTIONS)}")
    if experiment is not None:
        federation = experiment.federation
    keys.validate_name(federation, "federation name")
    fed = Federation(session, federation)
    try:
        time.sleep(discover)  # statuses arrive once a second
        seen = fed.snapshot()
        if experiment is not None:
            expected = frozenset(str(p.agent) for p in experiment.participants)
        else:
            expected = frozenset(seen)
        if not expected:
            raise ConnectError(f"no agent found in federation {federation!r} within {discover:g} s")
        ref = choose_reference(reference, experiment, seen)
        clock = ExecClock()
        ref_now = reference_now(session, federation, ref, clock)
        ref_offset = ref_now - clock.now()
        at = None
        if action == "start":
            if start_in is None:
                start_in = experiment.start_delay if experiment else DEFAULT_START_IN
            at = ref_now + start_in
            progress(f"start at reference time {at:.3f} s ({ref}'s clock)")
        command = Command(
            command=action,
            at=at,
            seq=time.time_ns() // 1_000_000,
            issued_at=clock.now() + ref_offset,
            issuer="ctl",
            experiment=experiment.name if experiment else None,
            maneuver=experiment.maneuver if experiment else None,
        )
        sent = time.monotonic()
        modes = send(session, federation, command, expected, fed, wait, progress)
        return ControlResult(command, ref, expected, modes, time.monotonic() - sent)
    finally:
        fed.close()

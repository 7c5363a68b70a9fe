"""Execution control over a federation: start, freeze, resume, abort or reset a run,
and the preflight table (``fedlab ctl status``).

``start`` first checks every participant (:mod:`federation.core.preflight`:
present, waiting, synchronized with the reference, platform ready, recording)
and starts nothing unless all pass on the participants' latest statuses within the
discovery time (a hold of a moment refuses nothing; ``force`` overrides and says what
it overrode). It names the run (``run_id``: the experiment's name and the UTC time,
unless given), syncs with the reference agent (the experiment's leader) exactly
as agents do, and announces a start at a reference time some seconds ahead,
with the run's duration; every agent begins when its own synchronized clock
reaches that instant, and is ``done`` after the duration.

``abort`` and ``reset`` are published at once, before anything is discovered or
synchronized, and act on receipt: nothing they need can be missing, and neither sets a
platform moving. ``freeze`` and ``resume``, like ``start``, take effect at a reference
instant announced ahead (``start_in`` s, by default the least that reaches every
participant with margin: :mod:`federation.core.lead`, from the one-way delays the
participants report and ctl's own to the reference): ctl syncs with the reference
clock the participants report and every agent applies the command when its own
synchronized clock reaches that instant, so every lab freezes (resumes) at the same
run time. A resume received more than a second after its instant (queued behind a cut
link) is ignored rather than set a platform moving at a time no one chose; without a
reference that answers (within a few seconds), or one all participants share, no
resume goes out. A freeze then goes out all the same, to act on receipt, and ctl says
why (a freeze late is a freeze now: it sets nothing moving).

Each :func:`issue` is a new issuer (host, pid and a random tag) numbering its
commands 1, 2, 3... (:class:`Issuer`): agents order commands per issuer
(:mod:`federation.core.commands`), so a bad seq or clock elsewhere cannot make
them ignore this one. Each command is published a few times with the same seq
(agents ignore repeats), then :func:`issue` waits, bounded, until every expected
agent reports the command's mode, and says for each one that did not why not
(its status lists what became of the last commands it received).
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import secrets
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from federation.core import keys
from federation.core.keys import AgentId
from federation.core.lead import delays_to, transition_lead
from federation.core.preflight import (
    DEFAULT_MAX_BOUND,
    DEFAULT_STALE_AFTER,
    Row,
    blocking,
    preflight,
)
from federation.runtime.clock import ExecClock
from federation.runtime.refclock import reference_now, reference_sync
from federation.runtime.session import ConnectError
from federation.runtime.statuses import Federation
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
    "Issuer",
    "PreflightFailed",
    "choose_reference",
    "issue",
    "make_run_id",
    "reference_now",
    "reference_sync",
    "send",
    "status",
]

Action = Literal["start", "freeze", "resume", "abort", "reset"]

EXPECTED_MODE: dict[str, frozenset[str]] = {
    "start": frozenset({"armed", "running", "done"}),
    "freeze": frozenset({"frozen"}),
    "resume": frozenset({"running"}),
    "abort": frozenset({"aborted"}),
    "reset": frozenset({"waiting", "unmanaged"}),
}
"""The modes an agent reports once it has taken each command (``unmanaged``: a legacy
agent's bridge, held from an abort until a reset, which runs its own timeline again)."""
ACTIONS: tuple[Action, ...] = ("start", "freeze", "resume", "abort", "reset")
DEFAULT_START_IN = 3.0
"""s between the announcement and a start, without an experiment's ``start_delay``."""


class PreflightFailed(ConnectionError):
    """A start refused: a participant is not ready. ``rows`` say who misses what."""

    def __init__(self, rows: list[Row]):
        self.rows = rows
        names = ", ".join(f"{r.agent} ({'; '.join(r.missing)})" for r in blocking(rows))
        super().__init__(f"not started: {names}")


class Issuer:
    """One issuer of commands: a name no other issuer has, and its own count."""

    def __init__(self, kind: str = "ctl"):
        host = socket.gethostname()[:60]
        self.name = f"{kind}@{host}:{os.getpid()}:{secrets.token_hex(4)}"
        self._seq = 0
        self._lock = threading.Lock()

    def next_seq(self) -> int:
        with self._lock:
            self._seq += 1
            return self._seq


def make_run_id(experiment: str | None, now: datetime.datetime | None = None) -> str:
    """``<experiment>-<UTC time>``, e.g. ``attitude-tracking-20250101T120000Z``."""
    now = now or datetime.datetime.now(datetime.UTC)
    return f"{experiment or 'run'}-{now.strftime('%Y%m%dT%H%M%SZ')}"


@dataclass(frozen=True)
class ControlResult:
    """A command as sent and the federation's answer to it."""

    command: Command
    reference: AgentId | None
    expected: frozenset[str]
    """Agents that had to confirm: the experiment's participants, else every agent seen."""
    modes: dict[str, str]
    """Every expected or seen agent (sorted) and its last reported mode; ``absent``: none."""
    elapsed: float
    """s from the first publication until all confirmed or the wait ran out."""
    sent_monotonic: float = 0.0
    """This host's ``time.monotonic()`` at the first publication."""
    reasons: dict[str, str] = field(default_factory=dict)
    """Why each pending agent did not confirm, as far as its status tells."""
    preflight: list[Row] = field(default_factory=list)
    overridden: list[str] = field(default_factory=list)
    """With ``force``: the preflight failures a start went ahead despite."""
    applied: dict[str, Any] = field(default_factory=dict)
    """Each agent's last transition applied, as its status says (event, reference
    instant ``at``, ``run_time``): a freeze or resume's instant, the same on each."""

    @property
    def pending(self) -> list[str]:
        """Expected agents that did not report the command's mode in time."""
        return sorted(a for a in self.expected if a not in self._confirmed())

    def _confirmed(self) -> set[str]:
        want = EXPECTED_MODE[self.command.command]
        return {a for a, m in self.modes.items() if m in want}

    @property
    def ok(self) -> bool:
        """Every expected agent confirmed."""
        return not self.pending

    def as_json(self) -> dict[str, Any]:
        return {
            "command": self.command.model_dump(),
            "reference": None if self.reference is None else str(self.reference),
            "ok": self.ok,
            "elapsed_s": self.elapsed,
            "sent_monotonic": self.sent_monotonic,
            "modes": self.modes,
            "pending": self.pending,
            "reasons": self.reasons,
            "overridden": self.overridden,
            "preflight": [r.as_json() for r in self.preflight],
            "applied": self.applied,
        }


def _accepted(status: dict[str, Any], command: Command) -> bool:
    """Whether an agent's status shows it in ``command``'s mode (a start: of this run)."""
    if status.get("mode") not in EXPECTED_MODE[command.command]:
        return False
    return command.command != "start" or status.get("run_id") == command.run_id


def why_not(status: dict[str, Any] | None, command: Command) -> str:
    """Why an agent has not confirmed ``command``, from its last status."""
    if status is None:
        return "no status received (agent absent or not reachable)"
    for outcome in reversed(status.get("commands") or []):
        if outcome.get("issuer") == command.issuer and outcome.get("seq") == command.seq:
            detail = outcome.get("detail") or ""
            return f"{outcome.get('outcome')}{': ' + detail if detail else ''}"
    return f"command not seen (mode {status.get('mode')})"


def publish(session: Any, federation: str, command: Command, copies: int = 3) -> float:
    """Publish ``command`` ``copies`` times (50 ms apart); the monotonic time of the first.
    An abort goes at real-time priority, express, and waits for room in a congested
    queue rather than being dropped (Zenoh's default for data is to drop)."""
    import zenoh

    payload = command.model_dump_json()
    key = keys.control_key(federation)
    options: dict[str, Any] = {}
    if command.command == "abort":
        options = {
            "priority": zenoh.Priority.REAL_TIME,
            "congestion_control": zenoh.CongestionControl.BLOCK,
            "express": True,
        }
    first = time.monotonic()
    for i in range(copies):
        if i:
            time.sleep(0.05)
        session.put(key, payload, **options)
    return first


RESEND_PERIOD = 0.5
"""s between copies of an abort while ctl waits for its confirmations."""
START_CONFIRM_MARGIN = 0.5
"""s before a start by which every participant must have confirmed it (else ctl aborts)."""
START_CONFIRM_MIN = 0.5
"""s: the least ctl waits for a start's confirmations."""
START_IN_MIN = START_CONFIRM_MIN + START_CONFIRM_MARGIN
"""s: the least time between announcing a start and the start: with less, the agents
present would begin (their platforms moving) before ctl could find one missing and
abort."""


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
    publish(session, federation, command)
    return confirm(command, expected, fed, timeout, progress)


def confirm(
    command: Command,
    expected: set[str] | frozenset[str],
    fed: Federation,
    timeout: float,
    progress: Callable[[str], None],
    resend: Callable[[], object] | None = None,
) -> dict[str, str]:
    """Wait (at most ``timeout`` s) until every ``expected`` agent reports ``command``;
    ``resend`` (an abort's) is called every :data:`RESEND_PERIOD` s meanwhile."""
    deadline = time.monotonic() + timeout
    next_send = time.monotonic() + RESEND_PERIOD
    while True:
        seen = fed.snapshot()
        pending = {a for a in expected if a not in seen or not _accepted(seen[a], command)}
        if not pending or time.monotonic() > deadline:
            break
        if resend is not None and time.monotonic() >= next_send:
            resend()  # the same command again: a repeat where it arrived, an abort where not
            next_send = time.monotonic() + RESEND_PERIOD
        time.sleep(0.05)
    if pending:
        progress(f"no confirmation within {timeout:g} s from: {', '.join(sorted(pending))}")
    modes = {a: s.get("mode", "?") for a, s in seen.items()}
    out = {a: modes.get(a, "absent") for a in sorted(set(expected) | set(modes))}
    for agent in pending:  # a start of another run is not this one's
        if agent in seen and command.command == "start" and out[agent] in EXPECTED_MODE["start"]:
            out[agent] = f"{out[agent]} ({seen[agent].get('run_id')})"
    return out


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


def status(
    session: Any,
    *,
    federation: str = keys.DEFAULT_FEDERATION,
    experiment: ExperimentConfig | None = None,
    discover: float = 1.5,
    max_bound: float = DEFAULT_MAX_BOUND,
    stale_after: float = DEFAULT_STALE_AFTER,
    fed: Federation | None = None,
) -> list[Row]:
    """The preflight table: every participant (and every other agent seen), each check."""
    if experiment is not None:
        federation = experiment.federation
    own = fed is None
    fed = fed or Federation(session, federation)
    try:
        fed.discover(_participants(experiment), discover)
        seen = fed.snapshot()
        participants = [p.agent for p in experiment.participants] if experiment else list(seen)
        return preflight(participants, seen, fed.ages(), max_bound, stale_after)
    finally:
        if own:
            fed.close()


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
    run_id: str | None = None,
    duration: float | None = None,
    force: bool = False,
    max_bound: float = DEFAULT_MAX_BOUND,
    issuer: Issuer | None = None,
    progress: Callable[[str], None] = lambda text: None,
) -> ControlResult:
    r"""Send ``action`` to every agent of a federation and collect their confirmations.

    Parameters
    ----------
    session
        An open Zenoh session.
    action
        ``start``, ``freeze``, ``resume``, ``abort`` or ``reset``.
    federation
        Federation name; an ``experiment``'s own name wins.
    experiment
        The run: its participants must confirm (and pass preflight), its leader is
        the reference, its maneuver, duration and ``start_delay`` go with a start.
    reference
        Agent whose clock is reference time (default: see :func:`choose_reference`).
    start_in
        s between now (reference time) and the start; default the experiment's
        ``start_delay``, else :data:`DEFAULT_START_IN`. For a freeze or resume, s between
        now and its instant; default the least that reaches every participant
        (:func:`federation.core.lead.transition_lead`).
    wait
        s to wait for confirmations.
    discover
        s to collect statuses first (agents publish one a second); an abort is
        published before.
    run_id
        The run's name (default :func:`make_run_id`).
    duration
        s of run time after which agents are done (default: the experiment's).
    force
        Start even if preflight fails; the result lists what was overridden.
    max_bound
        Preflight's largest accepted error bound of the reference clock's estimate (s).
    issuer
        Who issues (default: a new :class:`Issuer`).
    progress
        Called with a line of text on the way (start time, missing confirmations).

    The start instant, on the reference clock :math:`t_r`, is

    .. math:: t_{start} = t_r(now) + \Delta_{in},
              \qquad t_r(now) = t_{ctl}(now) + \hat\theta

    with :math:`\hat\theta` the offset estimated by a burst of sync exchanges.

    Raises
    ------
    PreflightFailed
        A start with a participant not ready (and no ``force``).
    ConnectError
        No agent seen in the federation, or the reference does not answer.
    ConfigError
        No single leader to take as the reference, or a ``run_id`` that an agent seen
        reports as its last run.
    """
    if action not in EXPECTED_MODE:
        raise ValueError(f"unknown action {action!r}: expected one of {', '.join(ACTIONS)}")
    if experiment is not None:
        federation = experiment.federation
    keys.validate_name(federation, "federation name")
    fed = Federation(session, federation)
    try:
        it = _Issuing(
            session, fed, federation, experiment, issuer or Issuer(), wait, discover, progress
        )
        if action in ("freeze", "resume"):
            return _issue_announced(it, action, reference, start_in)
        if action != "start":
            return _issue_on_receipt(it, action)
        return _issue_start(it, reference, start_in, run_id, duration, force, max_bound)
    finally:
        fed.close()


@dataclass(frozen=True)
class _Issuing:
    """What every step of one :func:`issue` shares: where it publishes, what it sees of
    the federation, the run, who numbers its commands, how long it discovers and waits,
    and where it reports."""

    session: Any
    fed: Federation
    federation: str
    experiment: ExperimentConfig | None
    issuer: Issuer
    wait: float
    discover: float
    progress: Callable[[str], None]

    def command(self, action: Action, **fields: Any) -> Command:
        """The issuer's next command ``action``, of the experiment if there is one."""
        return Command(
            command=action,
            seq=self.issuer.next_seq(),
            issuer=self.issuer.name,
            experiment=self.experiment.name if self.experiment else None,
            **fields,
        )

    def publish(self, command: Command, copies: int = 3) -> float:
        return publish(self.session, self.federation, command, copies)

    def resender(self, command: Command) -> Callable[[], object]:
        """One more copy of ``command`` each call (an abort's, while ctl waits)."""
        return lambda: self.publish(command, copies=1)


def _issue_on_receipt(it: _Issuing, action: Action) -> ControlResult:
    """An abort or a reset (or a freeze no reference time can be had for). Agents act on
    it on receipt, so there is nothing to look up first: it is published at once (an
    abort leaves before anything is discovered), then confirmed, an abort sent again
    while ctl waits."""
    experiment = it.experiment
    # An abort is for every agent; the rest for the experiment's only.
    command = it.command(
        action,
        participants=sorted(_expected(experiment, {}))
        if experiment is not None and action != "abort"
        else None,
    )
    sent = it.publish(command)
    it.fed.discover(_participants(experiment), it.discover - (time.monotonic() - sent))
    expected = _expected(experiment, it.fed.snapshot())
    if not expected:
        raise ConnectError(
            f"no agent found in federation {it.federation!r} within {it.discover:g} s "
            f"({action} was published on {keys.control_key(it.federation)})"
        )
    again = it.resender(command) if action == "abort" else None
    modes = confirm(command, expected, it.fed, it.wait, it.progress, resend=again)
    return _result(command, None, expected, modes, sent, it.fed)


def _start_in(
    start_in: float | None, duration: float | None, experiment: ExperimentConfig | None
) -> float:
    """The s between announcing a start and the start; ConfigError for a run without an
    end, or a start too soon for ctl to hear every confirmation and abort in time."""
    if duration is None and experiment is None:
        raise ConfigError(
            "a run must end: give --duration SECONDS or --experiment FILE (whose duration it takes)"
        )
    if start_in is None:
        start_in = experiment.start_delay if experiment else DEFAULT_START_IN
    if start_in < START_IN_MIN:
        raise ConfigError(
            f"a start {start_in:g} s ahead (--in, or the experiment's start_delay): it is "
            f"announced at least {START_IN_MIN:g} s ahead, so that ctl hears every "
            f"participant confirm it and can abort it {START_CONFIRM_MARGIN:g} s before it "
            "begins if one has not"
        )
    return start_in


def _issue_start(
    it: _Issuing,
    reference: AgentId | None,
    start_in: float | None,
    run_id: str | None,
    duration: float | None,
    force: bool,
    max_bound: float,
) -> ControlResult:
    """A start: checked, announced at a reference time ``start_in`` ahead, and aborted
    if a participant does not confirm it before it begins (unless ``force``)."""
    experiment = it.experiment
    start_in = _start_in(start_in, duration, experiment)
    # Waits for the participants' statuses (``discover`` s at most); the table is made
    # again below, with the reference chosen from them.
    status(
        it.session, federation=it.federation, experiment=experiment, discover=it.discover,
        max_bound=max_bound, fed=it.fed,
    )  # fmt: skip
    seen = it.fed.snapshot()
    expected = _expected(experiment, seen)
    if not expected:
        raise ConnectError(
            f"no agent found in federation {it.federation!r} within {it.discover:g} s"
        )
    ref = choose_reference(reference, experiment, seen)
    run_id = _fresh_run_id(run_id, experiment, seen)
    rows, overridden = _preflight_start(it, seen, ref, max_bound, force)
    clock = ExecClock()
    ref_now = reference_now(it.session, it.federation, ref, clock)
    ref_offset = ref_now - clock.now()
    at = ref_now + start_in
    it.progress(f"run {run_id}: start at reference time {at:.3f} s ({ref}'s clock)")
    if duration is None and experiment is not None:
        duration = experiment.duration
    command = it.command(
        "start",
        at=at,
        issued_at=clock.now() + ref_offset,
        maneuver=experiment.maneuver if experiment else None,
        run_id=run_id,
        # Only the agents preflighted and awaited: any other one ignores the start.
        participants=sorted(expected),
        duration=duration,
    )
    sent = it.publish(command)
    # Every participant confirms before the start, or none starts: a run without one
    # of its platforms is not the experiment (and the others would fly it alone).
    before_start = max(START_CONFIRM_MIN, start_in - START_CONFIRM_MARGIN)
    modes = confirm(command, expected, it.fed, min(it.wait, before_start), it.progress)
    result = _result(command, ref, expected, modes, sent, it.fed, rows, overridden)
    if result.pending and not force:
        return _abort_start(it, result, run_id)
    return result


def _preflight_start(
    it: _Issuing, seen: dict[str, Any], ref: AgentId, max_bound: float, force: bool
) -> tuple[list[Row], list[str]]:
    """The preflight rows of a start on ``ref``'s clock and the failures ``force``
    overrides; PreflightFailed if one fails without ``force``. A check failing for a
    moment (a hold while a pose is late on a loaded link) refuses nothing: the table is
    made again at each new status, for ``discover`` s at most, until every check passes
    on the participants' latest statuses."""
    experiment = it.experiment
    # Each participant must count time on the clock the start's instant is on.
    participants = [p.agent for p in experiment.participants] if experiment else list(seen)
    deadline = time.monotonic() + it.discover
    while True:
        looked = it.fed.count
        latest = it.fed.snapshot()
        rows = preflight(participants, latest, it.fed.ages(), max_bound, reference=str(ref))
        failed = blocking(rows)
        if not failed or force or (left := deadline - time.monotonic()) <= 0:
            break
        it.fed.wait_new(looked, left)
    overridden = [f"{r.agent}: {m}" for r in failed for m in r.missing]
    if failed and not force:
        raise PreflightFailed(rows)
    for line in overridden:
        it.progress(f"--force: starting although {line}")
    return rows, overridden


def _abort_start(it: _Issuing, result: ControlResult, run_id: str) -> ControlResult:
    """Abort a start some participant did not confirm in time; ``result`` with, for
    each agent, why it did not confirm the start or the abort."""
    abort = it.command("abort")
    it.publish(abort)
    missing = ", ".join(result.pending)
    it.progress(f"run {run_id} aborted: {missing} had not confirmed the start before it")
    # The abort is sent again until every participant confirms it (as `ctl abort`
    # does): the ones that did not confirm the start may take it late, on a slow link,
    # and would fly it alone. The result says who did not.
    aborted = confirm(abort, result.expected, it.fed, it.wait, it.progress, it.resender(abort))
    reasons = {a: f"{r}; the run was aborted before its start" for a, r in result.reasons.items()}
    for agent in sorted(a for a in result.expected if aborted.get(a) != "aborted"):
        said = reasons.get(agent, "took the start")
        reasons[agent] = (
            f"{said}; the abort sent after it not confirmed within {it.wait:g} s "
            f"(mode {aborted.get(agent, 'absent')})"
        )
    return dataclasses.replace(result, reasons=reasons)


def _fresh_run_id(
    run_id: str | None, experiment: ExperimentConfig | None, seen: dict[str, Any]
) -> str:
    """``run_id``, or a new one, that no agent seen reports as its last run.

    An agent refuses to record a run id over a run recorded on its host, and its
    refusal then aborts the start for everyone; a reused id seen in a status is refused
    here, before anything is sent. A default id (the time to the second) taken already
    gets a suffix."""

    def reported(candidate: str) -> list[str]:
        return sorted(a for a, s in seen.items() if s.get("run_id") == candidate)

    if run_id is not None:
        if taken := reported(run_id):
            raise ConfigError(
                f"--run-id {run_id}: {', '.join(taken)} reported it as their last run; "
                "a run id names one run: give another"
            )
        return run_id
    base = make_run_id(experiment.name if experiment else None)
    candidate, n = base, 1
    while reported(candidate):
        n += 1
        candidate = f"{base}-{n}"
    return candidate


def _participants(experiment: ExperimentConfig | None) -> frozenset[str] | None:
    """Whom ctl waits to hear from: the experiment's participants (None: every agent
    that answers within the discovery time)."""
    if experiment is None:
        return None
    return frozenset(str(p.agent) for p in experiment.participants)


def _expected(experiment: ExperimentConfig | None, seen: dict[str, Any]) -> frozenset[str]:
    """Whom a command is for: the experiment's participants, or every agent seen but a
    replay (``fedlab replay``: it follows the run from the others' status and confirms
    no command)."""
    participants = _participants(experiment)
    if participants is not None:
        return participants
    return frozenset(
        who for who, status in seen.items()
        if not str(status.get("platform") or "").startswith("replay:")
    )  # fmt: skip


def _issue_announced(
    it: _Issuing, action: Action, reference: AgentId | None, start_in: float | None
) -> ControlResult:
    """A freeze or resume at a reference instant announced ``start_in`` s ahead (see the
    module's notes); a freeze that cannot be timed goes out on receipt."""
    experiment = it.experiment
    it.fed.discover(_participants(experiment), it.discover)
    seen = it.fed.snapshot()
    expected = _expected(experiment, seen)
    if not expected:
        raise ConnectError(
            f"no agent found in federation {it.federation!r} within {it.discover:g} s: "
            f"{action} not sent"
        )
    try:
        ref = _shared_reference(expected, seen)
        if reference is not None and reference != ref:
            raise ConfigError(
                f"--reference {reference}, but the participants count time on {ref}'s clock"
            )
        ref_now, ctl_delay = reference_sync(it.session, it.federation, ref, ExecClock())
    except (ConfigError, ConnectError) as error:
        if action == "resume":  # a platform set moving whenever it arrives: not sent
            raise type(error)(f"resume not sent: {error}") from None
        it.progress(f"freeze on receipt, not at a common instant: {error}")
        return _issue_on_receipt(it, action)
    lead = transition_lead(delays_to(str(ref), sorted(expected), seen), ctl_delay)
    ahead = lead.seconds if start_in is None else start_in
    at = ref_now + ahead
    it.progress(
        f"{action} at reference time {at:.3f} s ({ref}'s clock), "
        f"{lead.describe() if start_in is None else f'{ahead:g} s ahead (--in)'}"
    )
    command = it.command(
        action, at=at, issued_at=ref_now,
        participants=sorted(_expected(experiment, {})) if experiment is not None else None,
    )  # fmt: skip
    sent = it.publish(command)
    modes = confirm(command, expected, it.fed, it.wait + ahead, it.progress)
    result = _result(command, ref, expected, modes, sent, it.fed)
    if result.pending and action == "resume":
        # Some flying, some frozen is no run: freeze them all again (as a start not every
        # participant confirmed is aborted), on receipt, and say so.
        it.publish(it.command("freeze", participants=command.participants))
        for agent in result.pending:
            result.reasons[agent] += "; freeze sent to all again"
        it.progress(f"not resumed by {', '.join(result.pending)}: freeze sent to all again")
    return result


def _shared_reference(expected: frozenset[str] | set[str], seen: dict[str, Any]) -> AgentId:
    """The reference clock every expected agent reports (their run's, whatever ctl would
    choose now); ConfigError when they report none or several."""
    absent = sorted(agent for agent in expected if not (seen.get(agent) or {}).get("reference"))
    if absent:
        raise ConfigError(
            f"the reference clock of {', '.join(absent)} is not known (no status from it)"
        )
    refs = {str(seen[agent]["reference"]) for agent in expected}
    if len(refs) != 1:
        raise ConfigError(
            f"the participants report {len(refs)} reference clocks "
            f"({', '.join(sorted(refs))}): not one run"
        )
    return AgentId.parse(refs.pop())


def _result(
    command: Command,
    reference: AgentId | None,
    expected: frozenset[str],
    modes: dict[str, str],
    sent: float,
    fed: Federation,
    rows: list[Row] | None = None,
    overridden: list[str] | None = None,
) -> ControlResult:
    seen = fed.snapshot()
    result = ControlResult(
        command, reference, expected, modes, time.monotonic() - sent, sent,
        preflight=rows or [], overridden=overridden or [],
    )  # fmt: skip
    reasons = {a: why_not(seen.get(a), command) for a in result.pending}
    applied = {a: seen[a].get("transition") for a in sorted(seen) if seen[a].get("transition")}
    return ControlResult(
        command, reference, expected, modes, result.elapsed, sent, reasons,
        result.preflight, result.overridden, applied,
    )  # fmt: skip

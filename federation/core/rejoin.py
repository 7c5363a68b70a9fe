"""Rejoining a run under way, free of I/O: the others' statuses and the present in, a
decision out.

An agent that (re)starts while its federation flies a run comes back ``waiting``; a
start it missed is refused as late (:data:`federation.core.runstate.LATE_START`). What
lets it back in is the run's announcement: every agent in a run publishes, in its
status, the run's id, its reference, its start instant on reference time, the time it
spent frozen, its duration, its experiment, its mode and run time
(:class:`schemas.messages.Status`). :func:`decide` reads the announcements seen and
the present reference time and says whether to join now, at which run time, or why
not.

The rules :func:`decide` keeps, each a row of :data:`CHECKS`, in order (the first
that refuses answers):

1. ``never``: this agent's policy refuses every rejoin.
2. Its guidance must be capturable without a step: a heading reference by
   :mod:`federation.core.capture`, a formation's or docking's position reference (a
   track) by :mod:`federation.core.track_capture`. What is left does not rejoin, and
   ``uncapturable`` says why: a plug-in scenario's reference (no capture is known for
   it), a drifting or turning docking target (its reference counts from where it stood
   at the start), a docking chaser nearer the target than its hold point or whose way
   there crosses the target's keep-out (it rejoins only before its final approach).
3. Only an agent ``waiting`` rejoins (one armed, running, frozen, done or aborted
   takes its runs from commands).
4. It must know the reference time now and pass its own preflight (its sync client
   locked, its platform ready: no fault hold, measurements fresh): joining needs the
   run's clock and a platform fit to fly.
5. An announcement counts only if it is fresh (its status's reference time within
   :data:`FRESH` of now), from another agent, for this agent's reference and
   experiment, of a run ``running`` with nothing armed (a freeze or resume to come:
   wait until it has applied). None counts: no run under way.
6. The announcements must agree (one run id, start instants within
   :data:`AGREE`): otherwise which run is under way cannot be told.
7. The run must have at least :data:`MIN_LEFT` of run time left.
8. ``operator``: only after an operator's admit (``fedlab ctl admit LAB/NAME``).

A decision that joins gives the run (:class:`Announcement`) and its run time now.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Literal

__all__ = [
    "AGREE",
    "CHECKS",
    "FRESH",
    "MIN_LEFT",
    "Announcement",
    "Decision",
    "Policy",
    "Situation",
    "announcement",
    "decide",
    "latest",
]

Policy = Literal["auto", "operator", "never"]

FRESH = 3.0
"""s of reference time after which an announcement (a status) is too old to count."""
AGREE = 0.05
"""s: two announcements of one run whose start instants differ by more disagree."""
MIN_LEFT = 2.0
"""s of run time a run must have left for a rejoin: less is not worth a capture."""


@dataclass(frozen=True)
class Announcement:
    """What one agent's status says of the run it flies."""

    agent: str
    run_id: str | None
    mode: str
    reference: str
    experiment: str | None
    t_sim: float | None
    """Reference time the status was made at, s."""
    start_at: float | None
    """The run's start instant on reference time, s."""
    frozen_total: float
    """s of reference time the run spent frozen so far."""
    duration: float | None
    armed: bool = False
    """A freeze or resume is armed for an instant to come."""

    def run_time(self, now: float) -> float:
        """The run's time at reference time ``now`` (running, nothing armed)."""
        assert self.start_at is not None
        return now - self.start_at - self.frozen_total


@dataclass(frozen=True)
class Situation:
    """Everything :func:`decide` reads."""

    me: str
    reference: str
    experiment: str | None
    mode: str
    policy: Policy
    admitted: bool
    now: float | None
    """Reference time now, s (None: not synchronized)."""
    seen: tuple[Announcement, ...]
    unready: str | None = None
    """Why its preflight fails (None: it passes)."""
    uncapturable: str | None = None
    """Why its reference cannot be captured without a step now (None: it can): the
    runtime's answer, from its scenario and, for a docking chaser, where it is."""


@dataclass(frozen=True)
class Decision:
    """Join (``run`` and ``run_time`` given) or not (``why``)."""

    join: bool
    why: str
    run: Announcement | None = None
    run_time: float | None = None
    waiting_admit: bool = False
    """A run it could join (``run``), waiting for an operator's admit (preflight's table
    says so)."""


def _counts(s: Situation, a: Announcement) -> bool:
    """Rule 4: a fresh announcement from another agent of a run this one would join."""
    return (
        a.agent != s.me
        and a.mode == "running"
        and not a.armed
        and a.run_id is not None
        and a.start_at is not None
        and a.duration is not None
        and a.t_sim is not None
        and s.now is not None
        and s.now - a.t_sim <= FRESH
        and a.reference == s.reference
        and a.experiment == s.experiment
    )


def _runs(s: Situation) -> list[Announcement]:
    return [a for a in s.seen if _counts(s, a)]


def _never(s: Situation) -> str | None:
    return "rejoin = never" if s.policy == "never" else None


def _uncapturable(s: Situation) -> str | None:
    return s.uncapturable


def _not_waiting(s: Situation) -> str | None:
    return None if s.mode == "waiting" else f"{s.mode}: only a waiting agent rejoins"


def _unsynchronized(s: Situation) -> str | None:
    return "no reference time: not synchronized" if s.now is None else None


def _unready(s: Situation) -> str | None:
    return None if s.unready is None else f"preflight: {s.unready}"


def _no_run(s: Situation) -> str | None:
    return None if _runs(s) else "no run under way"


def _disagree(s: Situation) -> str | None:
    runs = _runs(s)
    ids = {a.run_id for a in runs}
    if len(ids) > 1:
        return f"announcements disagree on the run: {', '.join(sorted(map(str, ids)))}"
    starts = [a.start_at + a.frozen_total for a in runs if a.start_at is not None]
    if max(starts) - min(starts) > AGREE:
        return f"announcements of run {runs[0].run_id} disagree on its clock"
    return None


def _ending(s: Situation) -> str | None:
    run, now = _runs(s)[0], s.now
    assert now is not None and run.duration is not None
    left = run.duration - run.run_time(now)
    if left < MIN_LEFT:
        return f"run {run.run_id} ends in {left:.1f} s: too near its end"
    return None


def _not_admitted(s: Situation) -> str | None:
    if s.policy == "operator" and not s.admitted:
        return f"waiting for an operator's admit (fedlab ctl admit {s.me})"
    return None


CHECKS: tuple[tuple[str, Callable[[Situation], str | None]], ...] = (
    ("never", _never),
    ("uncapturable", _uncapturable),
    ("not waiting", _not_waiting),
    ("unsynchronized", _unsynchronized),
    ("unready", _unready),
    ("no run", _no_run),
    ("disagree", _disagree),
    ("ending", _ending),
    ("not admitted", _not_admitted),
)
"""The module's rules 1 to 8, in order (rule 4 in two rows: synchronized, then its
preflight): a name and the check (why not, or None)."""


def decide(s: Situation) -> Decision:
    """Whether the agent of ``s`` joins the run under way now: the first check of
    :data:`CHECKS` that refuses says why not; else the run and its run time now."""
    for name, check in CHECKS:
        why = check(s)
        if why is not None:
            if name == "not admitted":  # the run it would join, for preflight's table
                return Decision(False, why, _runs(s)[0], waiting_admit=True)
            return Decision(False, why)
    run, now = _runs(s)[0], s.now
    assert now is not None
    return Decision(True, f"rejoin run {run.run_id}", run, run.run_time(now))


def announcement(agent: str, status: dict[str, object]) -> Announcement | None:
    """The announcement in one status (a dict, as decoded from its JSON); None if it
    names no run."""
    run_id = status.get("run_id")
    if not isinstance(run_id, str):
        return None

    def num(key: str) -> float | None:
        value = status.get(key)
        return float(value) if isinstance(value, (int, float)) else None

    experiment = status.get("experiment")
    return Announcement(
        agent=agent,
        run_id=run_id,
        mode=str(status.get("mode", "")),
        reference=str(status.get("reference", "")),
        experiment=experiment if isinstance(experiment, str) else None,
        t_sim=num("t_sim"),
        start_at=num("start_at"),
        frozen_total=num("frozen_total") or 0.0,
        duration=num("duration"),
        armed=status.get("armed") is not None,
    )


def latest(seen: Iterable[Announcement]) -> tuple[Announcement, ...]:
    """The newest announcement of each agent."""
    newest: dict[str, Announcement] = {}
    for a in seen:
        old = newest.get(a.agent)
        if old is None or (a.t_sim or float("-inf")) >= (old.t_sim or float("-inf")):
            newest[a.agent] = a
    return tuple(newest.values())

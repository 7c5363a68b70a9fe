"""The safety supervisor: may this platform's valves open, and if not, why not.

Every hold an agent (or a bridge) can be in is a :class:`Hold`; every happening that
sets or lifts one is a :class:`Trigger`. One table, :data:`RULES`, says for each hold

- the trigger that sets it,
- the triggers that lift it (none: it stands for good, until a new process),
- its rank (the hold shown when several stand: the first in the table),
- whether it stops a run from starting (``preflight``), and
- what it means and what lifts it, for operators (``docs/holds.md`` is written from it).

Holds are independent: each stands until one of its own lifting triggers comes, so a
trigger never lifts a hold it does not name, and the order in which two unrelated
triggers arrive does not matter. :class:`Supervisor` applies the table (lifts first,
then sets) and decides: the valves may open only while no hold stands.

The rules the table keeps, each checked by ``tests/unit/core/test_holds.py`` over
arbitrary sequences of triggers:

1. While any hold stands, the valves stay closed.
2. A hold for good (name taken, area left, own pose not finite, process ended) is
   never lifted.
3. An abort is lifted only by an operator's reset; so is an estimate restarted from
   outlier fixes. A confirmed reset leaves none of the holds it lifts.
4. A run's holds follow its mode: before its start the platform waits (``waiting``),
   after its end it is ``done``; a reset between runs is ``reset``. A rejoin (a run
   under way joined, :mod:`federation.core.rejoin`) lifts ``waiting`` and ``reset`` as
   a start does, and nothing else: a fault or a condition standing still holds.
5. Conditions lift on their own when they clear: a stale link, a contested peer, a
   lost router, the leader's role not held (:mod:`federation.core.standin`).

Pure: no clock, no I/O, no threads. The caller (the agent's
:class:`~federation.runtime.agent.safety.Safety`) feeds it triggers under one lock and
holds or releases the platform as it decides.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum, StrEnum

__all__ = [
    "RULES",
    "Change",
    "Hold",
    "Release",
    "Rule",
    "Supervisor",
    "Trigger",
    "holds_table_markdown",
]


class Hold(StrEnum):
    """Why every valve is closed. Its value is what status, preflight and the
    recordings say (``status.hold``)."""

    NAME_TAKEN = "name_taken"
    WORKSPACE = "workspace"
    NONFINITE = "nonfinite"
    FIX_RESTART = "fix_restart"
    ABORTED = "aborted"
    DONE = "done"
    RESET = "reset"
    CONTESTED = "contested"
    NO_ROUTER = "no_router"
    STALE = "stale"
    ROLE = "role"
    SOURCE_STALE = "source_stale"
    ENDED = "ended"
    WAITING = "waiting"


class Trigger(Enum):
    """What happened, as the agent's watches, its run state and its operator say it."""

    # The run (federation.core.runstate's events, and the operator's reset).
    RUN_ARMED = "run_armed"
    RUN_STARTED = "run_started"
    RUN_REJOINED = "run_rejoined"
    """The agent joined a run under way (federation.core.rejoin decided it)."""
    RUN_DONE = "run_done"
    RUN_ABORTED = "run_aborted"
    OPERATOR_RESET = "operator_reset"
    """A reset command the agent applied (confirmed), whatever the run's mode was."""
    # Conditions that come and go.
    LINK_STALE = "link_stale"
    LINK_RESUMED = "link_resumed"
    CONTESTED = "contested"
    CONTEST_CLEARED = "contest_cleared"
    ROUTER_LOST = "router_lost"
    ROUTER_BACK = "router_back"
    SOURCE_STALE = "source_stale"
    SOURCE_FRESH = "source_fresh"
    ROLE_LOST = "role_lost"
    """The leader's role (federation.core.standin) is not held by this agent (a leader)
    nor by one it follows (a follower)."""
    ROLE_HELD = "role_held"
    # Faults.
    FIX_RESTARTED = "fix_restarted"
    NAME_TAKEN = "name_taken"
    AREA_LEFT = "area_left"
    POSE_NONFINITE = "pose_nonfinite"
    ENDED = "ended"


class Release(StrEnum):
    """How a hold is lifted: the classes operators are told about."""

    NEVER = "never (a new process)"
    OPERATOR = "an operator's reset (fedlab ctl reset)"
    RUN = "the run (a start, a rejoin, or a reset)"
    ON_ITS_OWN = "on its own, when the condition clears"


@dataclass(frozen=True)
class Rule:
    """One row of :data:`RULES`."""

    hold: Hold
    set_by: Trigger
    lifted_by: frozenset[Trigger]
    release: Release
    preflight: bool
    """Whether it stops a run from starting (preflight says ``held (HOLD)``)."""
    meaning: str


def _rule(
    hold: Hold,
    set_by: Trigger,
    lifted_by: Iterable[Trigger],
    release: Release,
    preflight: bool,
    meaning: str,
) -> Rule:
    return Rule(hold, set_by, frozenset(lifted_by), release, preflight, meaning)


T, R = Trigger, Release
# fmt: off
RULES: tuple[Rule, ...] = (
    #     hold             set by            lifted by                        release     starts?
    _rule(Hold.NAME_TAKEN,  T.NAME_TAKEN,     (),                              R.NEVER,      True,
          "another process runs under this agent's name; which one is genuine cannot be "
          "told in-band: stop one, restart the other"),
    _rule(Hold.WORKSPACE,   T.AREA_LEFT,      (),                              R.NEVER,      True,
          "the platform left its lab's area (the scenario's frame holds it)"),
    _rule(Hold.NONFINITE,   T.POSE_NONFINITE, (),                              R.NEVER,      True,
          "the platform's own pose is not a finite number: never sent"),
    _rule(Hold.FIX_RESTART, T.FIX_RESTARTED,  (T.OPERATOR_RESET,),             R.OPERATOR,   True,
          "the estimate restarted from agreeing outlier fixes: right only if the "
          "metrology is; check it, then reset"),
    _rule(Hold.ABORTED,     T.RUN_ABORTED,    (T.OPERATOR_RESET,),             R.OPERATOR,   True,
          "the run was aborted (by an operator, or here: its reference restarted, its "
          "clock stepped, the router lost, the estimate restarted)"),
    _rule(Hold.DONE,        T.RUN_DONE,       (T.RUN_ARMED, T.OPERATOR_RESET), R.RUN,        False,
          "the run reached its duration"),
    _rule(Hold.RESET,       T.OPERATOR_RESET, (T.RUN_ARMED, T.RUN_REJOINED),   R.RUN,        False,
          "waiting for the next start (or a rejoin) after an operator's reset"),
    _rule(Hold.CONTESTED,   T.CONTESTED,      (T.CONTEST_CLEARED,),            R.ON_ITS_OWN, True,
          "two sources speak for the followed agent: nothing from it is used; lifted "
          "once the contest clears and a pose and a sync exchange came since"),
    _rule(Hold.NO_ROUTER,   T.ROUTER_LOST,    (T.ROUTER_BACK,),                R.ON_ITS_OWN, True,
          "the session has had no router for a second, after having one"),
    _rule(Hold.STALE,       T.LINK_STALE,     (T.LINK_RESUMED,),               R.ON_ITS_OWN, True,
          "the followed pose is stale; lifted once it flows again and a sync exchange "
          "completed since"),
    _rule(Hold.ROLE,        T.ROLE_LOST,      (T.ROLE_HELD,),                  R.ON_ITS_OWN, True,
          "an experiment with a stand-in: the leader does not hold the leader's role "
          "(unacknowledged by the stand-in, lapsed, or deposed until fedlab ctl handback), "
          "or a follower sees no agent hold it; lifted once it holds it (follows its holder)"),
    _rule(Hold.SOURCE_STALE, T.SOURCE_STALE,   (T.SOURCE_FRESH,),               R.ON_ITS_OWN, True,
          "the platform's own pose source (a ROS 2 bridge's odometry) is stale: no pose "
          "is published; lifted once it flows again"),
    _rule(Hold.ENDED,       T.ENDED,          (),                              R.NEVER,      True,
          "the agent's duration passed, or it is closing: the process ends"),
    _rule(Hold.WAITING,     T.RUN_ARMED,      (T.RUN_STARTED, T.RUN_REJOINED), R.RUN,        False,
          "waiting for its run to start (fedlab ctl start), or to rejoin a run under way "
          "(its rejoin policy: auto, or after fedlab ctl admit)"),
)
# fmt: on
"""Every hold, highest rank first (the one status shows when several stand)."""

_RANK = {rule.hold: rank for rank, rule in enumerate(RULES)}
_SETS = {trigger: frozenset(r.hold for r in RULES if r.set_by is trigger) for trigger in Trigger}
_LIFTS = {
    trigger: frozenset(r.hold for r in RULES if trigger in r.lifted_by) for trigger in Trigger
}
BY_HOLD = {rule.hold: rule for rule in RULES}


@dataclass(frozen=True)
class Change:
    """What one trigger did: the holds it set and lifted (each only if it changed)."""

    trigger: Trigger
    set: frozenset[Hold]
    lifted: frozenset[Hold]


class Supervisor:
    """The holds standing now, and the one decision: may the valves open.

    Starts holding :attr:`Hold.WAITING` (a platform waits for its run, held). The
    standing holds are one immutable set, replaced whole by :meth:`apply`: a reader on
    another thread (a status being built while a command is applied) sees the holds as
    they were before or after a trigger, never a set changing under it. Writers are
    serialized by the caller (:class:`~federation.runtime.safety.Safety`'s lock).
    """

    def __init__(self, standing: Iterable[Hold] = (Hold.WAITING,)):
        self._standing: frozenset[Hold] = frozenset(standing)

    def apply(self, trigger: Trigger) -> Change:
        """Apply ``trigger``: lift the holds it lifts, then set the one it sets."""
        before = self._standing
        lifted = _LIFTS[trigger] & before
        kept = before - lifted
        added = _SETS[trigger] - kept
        self._standing = kept | added
        return Change(trigger, added, lifted)

    @property
    def may_open(self) -> bool:
        """Whether the valves may open: no hold stands."""
        return not self._standing

    @property
    def hold(self) -> Hold | None:
        """The hold shown: the highest-ranked standing (None: the valves may open)."""
        return min(self._standing, key=_RANK.__getitem__, default=None)

    @property
    def standing(self) -> frozenset[Hold]:
        """Every hold standing now."""
        return self._standing

    def holds(self, hold: Hold) -> bool:
        """Whether ``hold`` stands."""
        return hold in self._standing

    def blocking(self) -> Hold | None:
        """The highest-ranked standing hold that stops a run from starting (preflight),
        None if only the run's own holds stand."""
        fault = (h for h in self._standing if BY_HOLD[h].preflight)
        return min(fault, key=_RANK.__getitem__, default=None)


def holds_table_markdown() -> str:
    """The table of :data:`RULES` as Markdown (``docs/holds.md``'s table)."""
    rows = [
        "| hold | set by | lifted by | how | stops a start | meaning |",
        "|---|---|---|---|---|---|",
    ]
    for r in RULES:
        lifted = ", ".join(sorted(t.value for t in r.lifted_by)) or "nothing"
        rows.append(
            f"| `{r.hold.value}` | `{r.set_by.value}` | {lifted} | {r.release.value} "
            f"| {'yes' if r.preflight else 'no'} | {r.meaning} |"
        )
    return "\n".join(rows) + "\n"

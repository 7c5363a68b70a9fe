"""The agent's watches: each looks at one thing at every control step and, when it
changes, names a trigger for the safety supervisor (:mod:`federation.core.holds`).

- the followed link: stale (no pose for the measured threshold) and resumed (poses
  again and a sync exchange completed since), and the followed agent contested
  (two sources speaking for it) and cleared (a pose and a sync exchange since);
- the session's router: lost for :data:`NO_ROUTER_HOLD` after having one, and back;
- the estimate restarted from agreeing outlier fixes (until an operator's reset);
- the name: another process answering this agent's sync key (for good);
- the area: the scenario's platform left its lab's area (for good).

A watch never holds or releases a platform itself; a run it cannot fly on is ended
here (:meth:`~federation.runtime.agent.commands.RunControl.end_run_here`).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from federation.core.counters import Count
from federation.core.holds import Hold, Trigger
from federation.runtime.names import NAME_CHECKS_AFTER, clash_message, look_again

if TYPE_CHECKING:
    from federation.runtime.agent.commands import RunControl
    from federation.runtime.agent.intake import PoseIntake
    from federation.runtime.agent.peers import PeerTable
    from federation.runtime.agent.services import AgentServices

__all__ = ["NO_ROUTER_HOLD", "ROUTER_CHECK_PERIOD", "Watches"]

log = logging.getLogger("fedlab.agent")

NO_ROUTER_HOLD = 1.0
"""s without a router (after having one) before an agent holds (``no_router``)."""
ROUTER_CHECK_PERIOD = 0.25
"""s between looks at the session's router."""


def _held_or_released(hold: Hold | None) -> str:
    return "released" if hold is None else f"held ({hold})"


class Watches:
    """The watches of ``owner`` (an agent) and what each last saw."""

    def __init__(
        self, owner: AgentServices, intake: PoseIntake, peer_table: PeerTable, commands: RunControl
    ):
        self.owner = owner
        self.intake = intake
        self.peer_table = peer_table
        self.commands = commands
        self._contest_cleared: float | None = None  # own time a followed contest cleared
        # The session's router: had one, lost since (host monotonic), next look.
        self._had_router = False
        self._router_lost: float | None = None
        self._router_check = 0.0
        # Host monotonic times of the later looks at the name (start + NAME_CHECKS_AFTER),
        # the next first; why the name is taken twice, once a look found another holder.
        self.name_checks: list[float] = []
        self.name_clash: str | None = None
        self.left_area = False  # the scenario's platform left its area

    def started(self, host: float) -> None:
        """The agent is up at host monotonic ``host``: the name is looked at again later."""
        self.name_checks = [host + after for after in NAME_CHECKS_AFTER]

    def look(self, host: float) -> None:
        """The name and the router, looked at on their own periods (host monotonic
        ``host``)."""
        self.check_name_again(host)
        if host >= self._router_check:
            self._router_check = host + ROUTER_CHECK_PERIOD
            self.watch_router(host)

    def step(self, t_exec: float, host: float) -> None:
        """The watches judged at every control step, at own time ``t_exec``."""
        if self.name_clash is not None and not self.owner.safety.holds(Hold.NAME_TAKEN):
            self._hold_for_name(t_exec, host)
        self.watch_link(t_exec, host)
        self.watch_fix_restart(host)

    # -- the name --------------------------------------------------------------------
    def check_name_again(self, host: float) -> None:
        """At each of ``NAME_CHECKS_AFTER`` after start: ask who answers this agent's own
        sync key (:func:`~federation.runtime.names.look_again`). Two processes that
        started under one name at once both passed the first look; each now hears the
        other's session besides its own, and each holds for good: which one is genuine
        cannot be told in-band. The replies come on Zenoh's threads; a query that
        cannot be sent is tried again a period later."""
        owner = self.owner

        def clash(sessions: list[str]) -> None:
            self.name_clash = clash_message(str(owner.me), owner.config.federation, sessions)

        key = owner.key(owner.me, "sync")
        look_again(self.name_checks, host, owner.session, key, owner.clock.now, clash)

    def _hold_for_name(self, t_exec: float, host: float) -> None:
        owner = self.owner
        owner.safety.apply(Trigger.NAME_TAKEN)
        owner.count(Count.NAME_TAKEN_HOLDS)
        log.error("%s: safe hold for good; stop one of them and restart the other", self.name_clash)
        owner.event("name_taken_hold", t_exec, host, self.name_clash or "")

    # -- the followed link -----------------------------------------------------------
    def watch_link(self, t_exec: float, host: float) -> None:
        """Safe hold while the followed pose is stale; lifted once it flows again and a
        sync exchange has completed since (re-synchronized). Watched whatever else
        holds: the stale hold is one of its own, lifted by nothing but the link."""
        owner = self.owner
        if owner.follow is None or self.watch_contest(t_exec, host):
            return
        intake = self.intake
        received = intake.pose_received_at.get(owner.follow)
        client = self.peer_table.client_of(owner.follow)
        last = None if client is None else client.last
        # On a shared feed the link is measured once for all its agents; the hold is each one's.
        threshold = None if intake.feed is None else intake.feed.watch.threshold
        action = intake.link_watch.update(
            t_exec, received, None if last is None else last.t3, threshold
        )
        if action == "stale_hold" and received is not None:
            owner.safety.apply(Trigger.LINK_STALE)
            owner.count(Count.STALE_HOLDS)
            log.warning(
                "no pose from %s for %.0f ms: safe hold", owner.follow, (t_exec - received) * 1e3
            )
            owner.event("stale_hold", t_exec, host, f"last pose {t_exec - received:.3f} s ago")
        elif action == "link_resumed":
            owner.safety.apply(Trigger.LINK_RESUMED)
            log.info(
                "pose from %s flows again and sync resumed: %s",
                owner.follow, _held_or_released(owner.safety.hold),
            )  # fmt: skip
            owner.event("link_resumed", t_exec, host, "")

    def watch_contest(self, t_exec: float, host: float) -> bool:
        """Safe hold while the followed agent is contested; once the contest clears,
        lifted only when a pose and a sync exchange have arrived since (True: held for
        it still)."""
        owner = self.owner
        follow = owner.follow
        assert follow is not None
        reason = self.intake.contest_reason(str(follow), host)
        safety = owner.safety
        if reason is not None:
            self._contest_cleared = None
            if not safety.holds(Hold.CONTESTED):
                safety.apply(Trigger.CONTESTED)
                owner.count(Count.CONTESTED_HOLDS)
                log.error("followed agent %s contested (%s): safe hold", follow, reason)
                owner.event("contested_hold", t_exec, host, reason)
            return True
        if not safety.holds(Hold.CONTESTED):
            return False
        if self._contest_cleared is None:
            self._contest_cleared = t_exec
        received = self.intake.pose_received_at.get(follow)
        client = self.peer_table.client_of(follow)
        last = None if client is None else client.last
        cleared = self._contest_cleared
        if received is None or received <= cleared or last is None or last.t3 <= cleared:
            return True
        safety.apply(Trigger.CONTEST_CLEARED)
        log.warning(
            "contest of %s cleared, pose and sync since: %s",
            follow, _held_or_released(safety.hold),
        )  # fmt: skip
        owner.event("contest_cleared", t_exec, host, "")
        return False

    # -- the router ------------------------------------------------------------------
    def watch_router(self, host: float) -> None:
        """Hold (``no_router``) once the session has had no router for ``NO_ROUTER_HOLD``
        seconds after having one, and end a ctl run here: a leader or member would fly
        on with no follower's stale watch to stop it, and no abort could reach it. Its
        router back, the hold is lifted. A session that never had one (a peer) is left
        alone."""
        owner = self.owner
        session = owner.session
        if session is None:
            return
        safety = owner.safety
        if any(True for _ in session.info.routers_zid()):
            self._had_router, self._router_lost = True, None
            if safety.holds(Hold.NO_ROUTER):
                safety.apply(Trigger.ROUTER_BACK)
                log.warning("router back: %s", _held_or_released(safety.hold))
            return
        if not self._had_router:
            return
        if self._router_lost is None:
            self._router_lost = host
        if host - self._router_lost < NO_ROUTER_HOLD or safety.holds(Hold.NO_ROUTER):
            return
        detail = f"no router for {host - self._router_lost:.1f} s"
        self.commands.end_run_here(Count.ROUTER_LOST, detail, host)
        safety.apply(Trigger.ROUTER_LOST)
        owner.count(Count.NO_ROUTER_HOLDS)
        log.error("%s: safe hold until it is back", detail)

    # -- the estimate ----------------------------------------------------------------
    def watch_fix_restart(self, host: float) -> None:
        """Hold (``fix_restart``) and end a ctl run here once the platform's estimate has
        restarted from agreeing outlier fixes: they are where the platform is only if the
        metrology is right (a frozen or glitching one repeats one wrong value). Lifted
        only by ``fedlab ctl reset``, which acknowledges it. Read from the platform's
        own flag, not the chain's reason (held, its reason is ``held``)."""
        owner = self.owner
        if not owner.platform.restarted or owner.safety.holds(Hold.FIX_RESTART):
            return
        detail = "the estimate restarted from agreeing outlier fixes: check the metrology"
        self.commands.end_run_here(Count.FIX_RESTART, detail, host)
        owner.safety.apply(Trigger.FIX_RESTARTED)
        owner.count(Count.FIX_RESTART_HOLDS)
        log.error("%s: safe hold until fedlab ctl reset", detail)

    # -- the area --------------------------------------------------------------------
    def watch_area(self, t_exec: float, host: float) -> None:
        """The scenario's platform left its area: its frame holds it already; the
        supervisor says so too, for good."""
        scenario = self.owner.scenario
        if scenario is None or not scenario.workspace_held or self.left_area:
            return
        self.left_area = True
        self.owner.safety.apply(Trigger.AREA_LEFT)
        detail = scenario.area_detail or ""
        log.warning("safe hold: %s", detail)
        self.owner.event("workspace_hold", t_exec, host, detail)

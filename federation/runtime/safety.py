"""The agent's safety supervisor at work: triggers in, the platform held or released.

:class:`Safety` owns an agent's :class:`~federation.core.holds.Supervisor` and the one
lock every hold and release is decided under, and it is the only code that holds a
platform for a cause or lets it go. The agent's watches (the link, the contest, the
router, the estimate, the name, the area), its run state's events and its operator's
commands only name what happened (a :class:`~federation.core.holds.Trigger`); the
table in :mod:`federation.core.holds` says what follows.

- A trigger that sets a hold closes every valve at once (``platform.hold()``), under
  the lock, before anything is logged or recorded.
- The platform is released only when a trigger lifts the last hold standing; never by
  a hold's setting, never by a step.
- :meth:`Safety.enforce`, called at every control step, holds again a platform that
  runs free while a hold stands (a release made elsewhere): a step never flies
  through a hold.
"""

from __future__ import annotations

import threading

from agents.interface import Platform
from federation.core.holds import Change, Hold, Supervisor, Trigger

__all__ = ["Safety"]


class Safety:
    """One agent's holds and the platform they keep closed.

    Parameters
    ----------
    platform : Platform
        What is held and released (the scenario's framed platform, if it has one).
    """

    def __init__(self, platform: Platform):
        self._platform = platform
        self._supervisor = Supervisor()
        self.lock = threading.Lock()
        """Taken for every decision; an abort takes it to close the valves and abort
        its run before any release can be decided (none judged before it follows)."""
        if not self._supervisor.may_open:  # an agent begins held (waiting for its run)
            platform.hold()

    def apply(self, trigger: Trigger) -> Change:
        """Apply ``trigger`` (takes :attr:`lock`)."""
        with self.lock:
            return self.apply_locked(trigger)

    def apply_locked(self, trigger: Trigger) -> Change:
        """Apply ``trigger``, :attr:`lock` held by the caller: valves closed at once if
        it set a hold; the platform released if it lifted the last one."""
        change = self._supervisor.apply(trigger)
        if change.set or not self._supervisor.may_open:
            if change.set or not self._platform.held:
                self._platform.hold()
        elif change.lifted and self._platform.held:
            self._platform.release()
        return change

    def close_valves(self) -> None:
        """Every valve closed now, :attr:`lock` held by the caller, ahead of the trigger
        that says why (an abort's run state is changed in between)."""
        self._platform.hold()

    def enforce(self) -> Hold | None:
        """Hold a platform found running free while a hold stands; the hold, if it did.
        Called at every control step: the common case (nothing stands, or the platform
        is held) is read without the lock, the standing holds being one immutable set."""
        if self._supervisor.may_open or self._platform.held:
            return None
        with self.lock:
            hold = self._supervisor.hold
            if hold is None or self._platform.held:
                return None
            self._platform.hold()
            return hold

    @property
    def hold(self) -> Hold | None:
        """The hold status shows (None: the valves may open)."""
        return self._supervisor.hold

    def holds(self, hold: Hold) -> bool:
        """Whether ``hold`` stands."""
        return self._supervisor.holds(hold)

    @property
    def standing(self) -> frozenset[Hold]:
        """Every hold standing."""
        return self._supervisor.standing

    def blocking(self) -> Hold | None:
        """The hold that stops a run from starting (preflight), if any."""
        return self._supervisor.blocking()

"""What ``fedlab ctl`` sees of a federation: every agent's latest status, when it came,
and a wait until the agents it is looking for have spoken."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

from federation.core import keys

__all__ = ["Federation"]


class Federation:
    """What ctl sees of a federation: every agent's latest status and when it came."""

    def __init__(self, session: Any, federation: str):
        import zenoh

        self.session = session
        self.federation = federation
        self.status: dict[str, dict[str, Any]] = {}
        self.received: dict[str, float] = {}  # agent -> time.monotonic() of its last status
        self.mismatched = 0  # statuses whose agent is not the one their key names: ignored
        self.count = 0  # statuses taken so far (for wait_new)
        self._lock = threading.Lock()
        self._new_status = threading.Condition(self._lock)
        self._sub = session.declare_subscriber(
            keys.all_of(federation, "status"),
            zenoh.handlers.Callback(self._on_status, indirect=False),
        )

    def _on_status(self, sample: Any) -> None:
        try:
            status = json.loads(sample.payload.to_bytes())
            # Filed under the key it came on, which only that agent may write: a status
            # naming another agent (an insider's "kiruna/knatte: aborted") is not that
            # agent's confirmation.
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            if parsed is None or parsed[1] != "status" or status["agent"] != str(parsed[0]):
                self.mismatched += 1
                return
            with self._lock:
                self.status[status["agent"]] = status
                self.received[status["agent"]] = time.monotonic()
                self.count += 1
                self._new_status.notify_all()
        except (ValueError, KeyError, TypeError):
            pass  # a malformed status is the monitor's business, not ctl's

    def discover(self, agents: frozenset[str] | None, timeout: float) -> None:
        """Collect statuses (agents publish one a second) until each of ``agents`` has
        one, for ``timeout`` s at most; with ``agents`` None (who is out there is what
        ctl is looking for), for the whole ``timeout``."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while agents is None or not agents <= self.status.keys():
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._new_status.wait(left)

    def wait_new(self, after: int, timeout: float) -> None:
        """Wait until a status arrives after the ``after``-th (:attr:`count` when the
        caller last looked; one that came meanwhile returns at once), ``timeout`` s at
        most."""
        with self._lock:
            self._new_status.wait_for(lambda: self.count != after, max(0.0, timeout))

    def snapshot(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return dict(self.status)

    def ages(self) -> dict[str, float]:
        now = time.monotonic()
        with self._lock:
            return {a: now - t for a, t in self.received.items()}

    def close(self) -> None:
        self._sub.undeclare()

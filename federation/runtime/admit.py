"""``fedlab ctl admit LAB/NAME``: let agents whose rejoin policy is ``operator`` (a real
platform's default) join the run under way.

An agent (re)started during a run waits, held, and says in its status the run it
would join (``admit_run``; preflight's table shows it). An admit is a command on the
control key like the others (:class:`schemas.messages.Command`, ``command = "admit"``,
naming its agents in ``participants``; the routers' access control lets only
operators publish there). The agent then joins at its next step, if the run is still
under way and it still passes its own preflight (:mod:`federation.core.rejoin`).
:func:`admit` publishes it and waits, bounded, until each agent named reports it
rejoined, or says why not (the command refused, or the agent's own ``rejoin`` reason).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from federation.core import keys
from federation.core.keys import AgentId
from federation.runtime.control import Issuer, publish, why_not
from federation.runtime.session import ConnectError
from federation.runtime.statuses import Federation
from schemas.messages import Command

__all__ = ["AdmitResult", "admit", "rejoined"]


@dataclass
class AdmitResult:
    """An admit as sent and each agent's answer."""

    command: Command
    modes: dict[str, str]
    """Each agent named and its last reported mode (``absent``: no status)."""
    joined: dict[str, float | None] = field(default_factory=dict)
    """Each agent that rejoined: the run time it joined at (s)."""
    reasons: dict[str, str] = field(default_factory=dict)
    """Why each agent that did not rejoin did not, as far as its status tells."""
    elapsed: float = 0.0

    @property
    def ok(self) -> bool:
        """Every agent named rejoined."""
        return set(self.joined) == set(self.modes)

    def as_json(self) -> dict[str, Any]:
        return {
            "command": self.command.model_dump(),
            "ok": self.ok,
            "elapsed_s": self.elapsed,
            "modes": self.modes,
            "joined": self.joined,
            "reasons": self.reasons,
        }


def rejoined(status: dict[str, Any] | None) -> float | None:
    """The run time an agent rejoined at, if its status says it rejoined a run it is
    flying (or has flown to its end); None otherwise."""
    if status is None or status.get("mode") not in ("running", "frozen", "done"):
        return None
    transition = status.get("transition") or {}
    if transition.get("event") != "rejoined":
        return None
    run_time = transition.get("run_time")
    return float(run_time) if isinstance(run_time, (int, float)) else None


def _refused(status: dict[str, Any] | None, command: Command) -> str | None:
    """Why an agent refused ``command``, if its status says it did."""
    if status is None:
        return None
    why = why_not(status, command)
    return None if why.startswith("command not seen") or why.startswith("applied") else why


def admit(
    session: Any,
    agents: list[AgentId],
    *,
    federation: str = keys.DEFAULT_FEDERATION,
    wait: float = 10.0,
    discover: float = 1.5,
    issuer: Issuer | None = None,
    progress: Callable[[str], None] = lambda text: None,
) -> AdmitResult:
    """Admit ``agents`` into the run under way and wait (at most ``wait`` s) until each
    rejoined or refused.

    Raises
    ------
    ConnectError
        None of ``agents`` seen in the federation within ``discover`` s.
    """
    keys.validate_name(federation, "federation name")
    names = sorted({str(a) for a in agents})
    issuer = issuer or Issuer()
    fed = Federation(session, federation)
    try:
        fed.discover(frozenset(names), discover)
        if not any(a in fed.snapshot() for a in names):
            raise ConnectError(
                f"none of {', '.join(names)} found in federation {federation!r} within "
                f"{discover:g} s: nothing admitted"
            )
        for name in names:
            admit_run = (fed.snapshot().get(name) or {}).get("admit_run")
            progress(f"{name}: admitting into {admit_run or 'no run it awaits an admit for'}")
        command = Command(
            command="admit", seq=issuer.next_seq(), issuer=issuer.name, participants=names
        )
        sent = publish(session, federation, command)
        deadline = sent + wait
        while True:
            seen = fed.snapshot()
            settled = {
                a for a in names
                if rejoined(seen.get(a)) is not None or _refused(seen.get(a), command)
            }  # fmt: skip
            if settled == set(names) or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        result = AdmitResult(command, {}, elapsed=time.monotonic() - sent)
        for name in names:
            status = seen.get(name)
            result.modes[name] = "absent" if status is None else str(status.get("mode"))
            joined = rejoined(status)
            if joined is not None:
                result.joined[name] = joined
                continue
            refused = _refused(status, command)
            own = None if status is None else status.get("rejoin")
            result.reasons[name] = refused or own or why_not(status, command)
        return result
    finally:
        fed.close()

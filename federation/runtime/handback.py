"""``fedlab ctl handback LAB/NAME``: hand the leader's role back to a deposed leader.

In an experiment with a stand-in (:mod:`federation.core.standin`), a leader that saw
the stand-in take its role is deposed: it holds (``role``) until an operator hands
the role back. A handback is a command on the control key like the others
(:class:`schemas.messages.Command`, ``command = "handback"``, naming the leader in
``participants``; the routers' access control lets only operators publish there). The
stand-in releases the role :data:`~federation.core.standin.HANDOVER` later; the leader
asks for a new epoch, which the stand-in acknowledges once it no longer holds.
:func:`handback` publishes it and waits, bounded, until the leader's status says it
holds the role again (its ``claim``), or says why not (the command refused by the
leader or its stand-in, or the leader's own ``why``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from federation.core import keys
from federation.core.keys import AgentId
from federation.runtime.control import Issuer, publish, why_not
from federation.runtime.session import ConnectError
from federation.runtime.statuses import Federation
from schemas.messages import Command

__all__ = ["HandbackResult", "handback", "holds_role"]


@dataclass
class HandbackResult:
    """A handback as sent and what the leader and its stand-in said."""

    command: Command
    leader: str
    epoch: int | None = None
    """The epoch the leader holds again (None: it does not)."""
    why: str = ""
    """Why it does not hold, as its status and the stand-in's tell."""
    stand_in: str | None = None
    elapsed: float = 0.0

    @property
    def ok(self) -> bool:
        """The leader holds the role again."""
        return self.epoch is not None

    def as_json(self) -> dict[str, Any]:
        return {
            "command": self.command.model_dump(), "ok": self.ok, "leader": self.leader,
            "epoch": self.epoch, "stand_in": self.stand_in, "why": self.why,
            "elapsed_s": self.elapsed,
        }  # fmt: skip


def holds_role(status: dict[str, Any] | None, above: int = 0) -> int | None:
    """The epoch an agent's status says it holds, if above ``above``; None otherwise."""
    claim = None if status is None else status.get("claim")
    if not isinstance(claim, dict) or claim.get("holding") is not True:
        return None
    epoch = claim.get("epoch")
    return epoch if isinstance(epoch, int) and epoch > above else None


def _refused(status: dict[str, Any] | None, command: Command) -> str | None:
    if status is None:
        return None
    why = why_not(status, command)
    return why if why.startswith("ignored") or why.startswith("stale") else None


def handback(
    session: Any,
    leader: AgentId,
    *,
    federation: str = keys.DEFAULT_FEDERATION,
    wait: float = 10.0,
    discover: float = 1.5,
    issuer: Issuer | None = None,
    progress: Callable[[str], None] = lambda text: None,
) -> HandbackResult:
    """Hand the role back to ``leader`` and wait (at most ``wait`` s) until it holds it
    again, or the leader or its stand-in refuses.

    Raises
    ------
    ConnectError
        The leader not seen in the federation within ``discover`` s.
    """
    keys.validate_name(federation, "federation name")
    name = str(leader)
    issuer = issuer or Issuer()
    fed = Federation(session, federation)
    try:
        fed.discover(frozenset([name]), discover)
        status = fed.snapshot().get(name)
        if status is None:
            raise ConnectError(
                f"{name} not found in federation {federation!r} within {discover:g} s: "
                "nothing handed back"
            )
        claim = status.get("claim")
        if not isinstance(claim, dict) or claim.get("kind") != "leader":
            raise ConnectError(
                f"{name} keeps no leader's role (its experiment names no stand-in, or it is "
                "not the leader): nothing to hand back"
            )
        progress(f"{name}: {claim.get('why')}; handing the role back")
        before = max(int(claim.get("top") or 0), int(claim.get("epoch") or 0))
        command = Command(
            command="handback", seq=issuer.next_seq(), issuer=issuer.name, participants=[name]
        )
        sent = publish(session, federation, command)
        deadline = sent + wait
        while True:
            seen = fed.snapshot()
            # The leader's refusal ends the wait; its stand-in's (no role to release, say)
            # is told, and the leader may hold all the same.
            refused = _refused(seen.get(name), command)
            if holds_role(seen.get(name), before) is not None or refused:
                break
            if time.monotonic() > deadline:
                break
            time.sleep(0.05)
        result = HandbackResult(command, name, elapsed=time.monotonic() - sent)
        result.epoch = holds_role(seen.get(name), before)
        kinds = {a: ((s or {}).get("claim") or {}).get("kind") for a, s in seen.items()}
        result.stand_in = next((a for a, kind in kinds.items() if kind == "stand-in"), None)
        said = None if result.stand_in is None else _refused(seen.get(result.stand_in), command)
        if result.epoch is None:
            own = (seen.get(name) or {}).get("claim") or {}
            why = refused or own.get("why") or why_not(seen.get(name), command)
            result.why = "; ".join(
                str(w) for w in (why, said and f"{result.stand_in}: {said}") if w
            )
        return result
    finally:
        fed.close()

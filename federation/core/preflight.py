"""Is a federation ready for a run? Free of I/O: statuses and their ages in, a table out.

``fedlab ctl start`` starts nothing until every participant passes every check;
``fedlab ctl status`` prints the same table at any time. For each participant,
from its last status line (a dict as :class:`schemas.messages.Status` dumps it)
and how long ago it arrived:

==========  ================================================================
present     a status arrived within ``stale_after`` s
waiting     mode ``waiting`` or ``done`` (ready for a start)
synced      the reference itself, or its estimate of the reference clock is
            locked with an error bound (``ready.reference_bound``) at most
            ``max_bound`` s
platform    ``ready.platform``: not in a fault hold (stale link, aborted), its
            measurements fresh
recording   ``ready.recording``: the run will be recorded
peers       no peer it syncs with is alive but silent (``peers.<agent>.silent``:
            a peer whose liveliness token is up but that has answered no sync
            request for 2 s); the silent ones are named with how long
==========  ================================================================

A row also names the run under way an agent waits to be admitted to
(``admit_run``: its rejoin policy is ``operator``; ``fedlab ctl admit LAB/NAME`` lets
it join).

A check that fails says why in its cell (``absent``, ``mode running``,
``not locked``, ``bound 12.3 ms > 10 ms``...).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "CHECKS",
    "DEFAULT_MAX_BOUND",
    "DEFAULT_STALE_AFTER",
    "Check",
    "Row",
    "blocking",
    "named_silent",
    "preflight",
    "silent_peers",
]

CHECKS = ("present", "waiting", "synced", "platform", "recording", "peers")
DEFAULT_MAX_BOUND = 0.010
"""s: the largest error bound of the reference clock's estimate accepted for a start."""
DEFAULT_STALE_AFTER = 3.0
"""s without a status after which an agent is absent (agents report once a second)."""


@dataclass(frozen=True)
class Check:
    ok: bool
    detail: str = ""


@dataclass(frozen=True)
class Row:
    """One participant: each check's result, and what else is known."""

    agent: str
    checks: dict[str, Check] = field(default_factory=dict)
    mode: str | None = None
    run_id: str | None = None
    participant: bool = True
    admit_run: str | None = None
    """The run under way it joins once an operator admits it (none: it awaits no admit)."""

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks.values())

    @property
    def missing(self) -> list[str]:
        """``check: detail`` of every failed check."""
        return [f"{name}: {c.detail}" for name, c in self.checks.items() if not c.ok]

    def as_json(self) -> dict[str, Any]:
        return {
            "agent": self.agent,
            "participant": self.participant,
            "ok": self.ok,
            "mode": self.mode,
            "run_id": self.run_id,
            "admit_run": self.admit_run,
            "checks": {k: {"ok": c.ok, "detail": c.detail} for k, c in self.checks.items()},
        }


def _synced(status: Mapping[str, Any], max_bound: float, reference: str | None = None) -> Check:
    ready = status.get("ready") or {}
    own = status.get("reference")
    if reference is not None and own != reference:
        # A start's instant is on the reference's clock; an agent counting time on
        # another's (its own, say) would start early or late by their difference.
        return Check(False, f"on {own}'s clock, not the reference {reference}'s")
    if own == status.get("agent"):
        return Check(True, "reference")
    if status.get("t_sim") is None:
        return Check(False, "no reference time yet")
    if not ready.get("reference_locked"):
        return Check(False, "not locked")
    bound = ready.get("reference_bound")
    if not isinstance(bound, int | float):
        return Check(False, "no error bound")
    if bound > max_bound:
        return Check(False, f"bound {bound * 1e3:.2f} ms > {max_bound * 1e3:g} ms")
    return Check(True, f"bound {bound * 1e3:.2f} ms")


def silent_peers(status: Mapping[str, Any]) -> dict[str, float]:
    """The peers ``status`` reports alive but silent, and for how long (s)."""
    peers = status.get("peers")
    if not isinstance(peers, Mapping):
        return {}
    out = {}
    for name, peer in peers.items():
        silent = peer.get("silent") if isinstance(peer, Mapping) else None
        if isinstance(silent, int | float) and not isinstance(silent, bool):
            out[str(name)] = float(silent)
    return out


def named_silent(silent: Mapping[str, float]) -> str:
    """``kiruna/knatte 2.3 s, ...``: silent peers by name, for a table or a check."""
    return ", ".join(f"{name} {s:.1f} s" for name, s in sorted(silent.items()))


def _peers(status: Mapping[str, Any]) -> Check:
    silent = silent_peers(status)
    if silent:
        return Check(False, f"alive but silent: {named_silent(silent)}")
    return Check(True, "none silent")


def _row(
    agent: str,
    status: Mapping[str, Any] | None,
    age: float | None,
    limits: tuple[float, float],
    reference: str | None = None,
) -> Row:
    max_bound, stale_after = limits
    if status is None or age is None:
        absent = Check(False, "absent")
        return Row(agent, {name: absent for name in CHECKS})
    ready = status.get("ready") or {}
    mode = str(status.get("mode"))
    checks = {
        "present": Check(age <= stale_after, f"last status {age:.1f} s ago"),
        "waiting": Check(mode in ("waiting", "done"), f"mode {mode}"),
        "synced": _synced(status, max_bound, reference),
        "platform": Check(
            bool(ready.get("platform")),
            str(ready.get("platform_detail") or "no readiness reported"),
        ),
        "recording": Check(
            bool(ready.get("recording")), str(ready.get("recording_to") or "not recording")
        ),
        "peers": _peers(status),
    }
    admit_run = status.get("admit_run")
    admit = admit_run if isinstance(admit_run, str) else None
    return Row(agent, checks, mode, status.get("run_id"), admit_run=admit)


def preflight(
    participants: Iterable[str],
    statuses: Mapping[str, Mapping[str, Any]],
    ages: Mapping[str, float],
    max_bound: float = DEFAULT_MAX_BOUND,
    stale_after: float = DEFAULT_STALE_AFTER,
    reference: str | None = None,
) -> list[Row]:
    """One row per participant (sorted), then one per other agent seen; ``reference``:
    the agent whose clock a start's instant is on (each participant must count time
    on it)."""
    expected = sorted(set(participants))
    others = sorted(set(statuses) - set(expected))
    limits = (max_bound, stale_after)
    rows = [_row(a, statuses.get(a), ages.get(a), limits, reference) for a in expected]
    for agent in others:
        row = _row(agent, statuses.get(agent), ages.get(agent), limits)
        rows.append(dataclasses.replace(row, participant=False))
    return rows


def blocking(rows: Iterable[Row]) -> list[Row]:
    """The participants that are not ready (others seen do not block a start)."""
    return [r for r in rows if r.participant and not r.ok]

"""Whether each participant completed its run, and the run time it reached, from its
recording.

An agent records its run's end as a ``/control`` event: ``done`` when its run time
reached the duration, ``aborted`` when the run was aborted. A recording with neither
is of an agent whose process stopped (Ctrl-C, SIGTERM) or was killed before its run
ended: never complete, however far the others flew. The run time reached is the
largest an agent recorded (its ``/reference`` rows, ``/status`` lines and ``/control``
events). The
participants are every agent recorded, every agent of ``run.json`` and every agent a
recorded start named; one without a recording reached nothing known.
"""

from __future__ import annotations

from typing import Any

from federation.core.channels import Channel
from federation.report.load import AgentRecording, Run

__all__ = ["ENDS", "completion", "incomplete_notes", "participants", "summary_lines"]

ENDS = frozenset({"done", "aborted"})
"""The ``/control`` events that end a run."""
_RUN_MODES = frozenset({"running", "frozen", "done", "aborted"})


def completion(rec: AgentRecording) -> dict[str, Any]:
    """One participant: ``reached_s`` (run time reached, None if it never ran),
    ``complete`` (its run ended ``done``) and ``ended`` (``done``, ``aborted``, or
    ``stopped early``: no end recorded)."""
    control = rec.channel(Channel.CONTROL)
    rows = [*rec.channel(Channel.REFERENCE), *rec.channel(Channel.STATUS)]
    times = [m.get("run_time") for m in rows if m.get("mode") in _RUN_MODES]
    times += [e.get("run_time") for e in control if e.get("event") in ("frozen", "resumed", *ENDS)]
    numbers = [float(t) for t in times if isinstance(t, int | float) and not isinstance(t, bool)]
    ends = [str(e["event"]) for e in control if e.get("event") in ENDS]
    ended = ends[-1] if ends else "stopped early"
    return {
        "reached_s": max(numbers) if numbers else None,
        "complete": ended == "done",
        "ended": ended,
    }


def _named(run: Run) -> list[str]:
    """Every participant: recorded, in run.json, or named by a recorded start."""
    named = set(run.agents) | set((run.meta or {}).get("agents") or {})
    for rec in run.agents.values():
        for event in rec.channel(Channel.CONTROL):
            command = event.get("command") if event.get("event") == "command" else None
            if isinstance(command, dict) and command.get("command") == "start":
                named |= {str(a) for a in command.get("participants") or []}
    return sorted(named)


def participants(run: Run) -> dict[str, dict[str, Any]]:
    """:func:`completion` of every participant (one without a recording: ``ended``
    ``no recording``, never complete)."""
    out: dict[str, dict[str, Any]] = {}
    for agent in _named(run):
        rec = run.agents.get(agent)
        if rec is None:
            out[agent] = {"reached_s": None, "complete": False, "ended": "no recording"}
        else:
            out[agent] = completion(rec)
    return out


def incomplete_notes(parts: dict[str, dict[str, Any]]) -> list[str]:
    """A note for each participant that ran but did not complete: its figures are of
    the part it flew."""
    return [
        f"{agent} did not complete the run ({part['ended']} at run time "
        f"{part['reached_s']:.1f} s): its figures cover that part only"
        for agent, part in parts.items()
        if not part["complete"] and part["reached_s"] is not None
    ]


def _how(entry: dict[str, Any]) -> str:
    return {
        "done": "completed",
        "aborted": "aborted",
        "stopped early": "stopped early: no end recorded (its process stopped or was killed)",
        "no recording": "no recording",
    }.get(str(entry.get("ended")), str(entry.get("ended")))


def summary_lines(parts: dict[str, dict[str, Any]], duration: float | None) -> list[str]:
    """One line per participant: the run time it reached (of the duration) and whether
    it completed the run."""
    of = "" if duration is None else f" of {duration:g} s"
    lines = []
    for agent, entry in parts.items():
        reached = entry.get("reached_s")
        shown = "no run time" if reached is None else f"reached {reached:.1f} s{of}"
        lines.append(f"{agent}: {shown}, {_how(entry)}")
    return lines

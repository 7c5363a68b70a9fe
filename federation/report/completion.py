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

An agent killed mid-run and started again may rejoin it (``rejoined``): it records
the rest of the run as a new segment. Each segment runs from its ``started`` (run
time 0) or ``rejoined`` event to the largest run time it recorded; between two
segments is a gap, of run time the agent did not fly. A participant with a gap is not
complete either, even if it ended ``done``: it flew the run's end, not all of it.

In an experiment with a stand-in (:mod:`federation.core.standin`), an agent's
``/reference`` rows name the holder of the leader's role its reference came from
(``holder``: the leader, its stand-in, or none). The run time during which that holder
was neither the leader nor nobody is a stand-in period (``stand_in_s``: [from, to,
holder]): a follower's figures then are against the stand-in, and the stand-in's own
rows mark the time it flew the leader's role.
"""

from __future__ import annotations

import itertools
from typing import Any

from federation.core.channels import Channel
from federation.report.load import AgentRecording, Messages, Run

__all__ = [
    "ENDS",
    "NO_RECORDING",
    "completion",
    "gaps",
    "incomplete_notes",
    "participants",
    "segments",
    "stand_in_periods",
    "summary_lines",
]

ENDS = frozenset({"done", "aborted"})
"""The ``/control`` events that end a run."""
_SPAN_EVENTS = frozenset({"frozen", "resumed", "rejoined", *ENDS})
"""The ``/control`` events whose run time a participant reached."""
_RUN_MODES = frozenset({"running", "frozen", "done", "aborted"})


def _numbers(times: list[Any]) -> list[float]:
    return [float(t) for t in times if isinstance(t, int | float) and not isinstance(t, bool)]


def _reached(messages: Messages) -> list[float]:
    """Every run time a segment's messages recorded."""
    control = messages.get(Channel.CONTROL) or []
    rows = [*(messages.get(Channel.REFERENCE) or []), *(messages.get(Channel.STATUS) or [])]
    times = [m.get("run_time") for m in rows if m.get("mode") in _RUN_MODES]
    times += [e.get("run_time") for e in control if e.get("event") in _SPAN_EVENTS]
    return _numbers(times)


def segments(rec: AgentRecording) -> list[tuple[float, float]]:
    """The run time each segment of ``rec`` flew, (from, to) s: from its start (0) or
    rejoin, to the largest run time it recorded; none for a segment that never ran."""
    spans = []
    for messages in rec.segments or [rec.messages]:
        times = _reached(messages)
        if not times:
            continue
        control = messages.get(Channel.CONTROL) or []
        begun = [e for e in control if e.get("event") in ("started", "rejoined")]
        first = _numbers([begun[0].get("run_time")]) if begun else []
        spans.append((first[0] if first else min(times), max(times)))
    return spans


def gaps(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The run time between consecutive segments, (from, to) s."""
    return [(a[1], b[0]) for a, b in itertools.pairwise(spans) if b[0] > a[1]]


def stand_in_periods(rec: AgentRecording, leader: str | None) -> list[list[Any]] | None:
    """The run time ``rec``'s reference came from a holder of the leader's role other
    than ``leader`` (and none), [from, to, holder] in order: consecutive ``/reference``
    rows of one holder make one period. None: its rows name no holder (no stand-in)."""
    rows = [
        r for r in rec.channel(Channel.REFERENCE)
        if "holder" in r and r.get("mode") in _RUN_MODES and _numbers([r.get("run_time")])
    ]  # fmt: skip
    if not rows:
        return None
    periods: list[list[Any]] = []
    for holder, run in itertools.groupby(rows, key=lambda r: r.get("holder")):
        times = _numbers([r.get("run_time") for r in run])
        if holder is not None and holder != leader:
            periods.append([min(times), max(times), str(holder)])
    return periods


def completion(rec: AgentRecording, leader: str | None = None) -> dict[str, Any]:
    """One participant: ``reached_s`` (run time reached, None if it never ran),
    ``complete`` (its run ended ``done`` with no gap), ``ended`` (``done``, ``aborted``,
    or ``stopped early``: no end recorded), ``segments_s`` (the run time each segment
    flew, [from, to] s), ``gaps_s`` (the run time between them, [from, to] s) and, if
    its reference names the role's holder, ``stand_in_s`` (:func:`stand_in_periods`
    with the run's ``leader``)."""
    control = rec.channel(Channel.CONTROL)
    numbers = _reached(rec.messages)
    ends = [str(e["event"]) for e in control if e.get("event") in ENDS]
    ended = ends[-1] if ends else "stopped early"
    spans = segments(rec)
    holes = gaps(spans)
    return {
        "reached_s": max(numbers) if numbers else None,
        "complete": ended == "done" and not holes,
        "ended": ended,
        "segments_s": [list(span) for span in spans],
        "gaps_s": [list(hole) for hole in holes],
    } | _stand_in(rec, leader)


def _stand_in(rec: AgentRecording, leader: str | None) -> dict[str, Any]:
    periods = stand_in_periods(rec, leader)
    return {} if periods is None else {"stand_in_s": periods}


NO_RECORDING: dict[str, Any] = {
    "reached_s": None, "complete": False, "ended": "no recording", "segments_s": [], "gaps_s": [],
}  # fmt: skip
"""What is known of a participant without a recording."""


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
    leader = run.leader
    for agent in _named(run):
        rec = run.agents.get(agent)
        if rec is None:
            out[agent] = dict(NO_RECORDING)
        else:
            out[agent] = completion(rec, leader)
    return out


def incomplete_notes(parts: dict[str, dict[str, Any]]) -> list[str]:
    """A note for each participant that ran but did not complete: its figures are of
    the part it flew; and one for each that flew stand-in periods: whose reference it
    then had."""
    notes = [
        f"{agent}'s reference came from the stand-in {holder} from {a:.1f} to {b:.1f} s "
        "of run time (the leader lost): its figures then are against the stand-in"
        if holder != agent
        else f"{agent} held the leader's role from {a:.1f} to {b:.1f} s of run time"
        for agent, part in parts.items()
        for a, b, holder in part.get("stand_in_s") or []
    ]
    for agent, part in parts.items():
        if part["complete"] or part["reached_s"] is None:
            continue
        holes = part.get("gaps_s") or []
        if holes:
            notes.append(
                f"{agent} flew the run in {len(part.get('segments_s') or [])} segments, "
                f"not from {_spans(holes)} s of run time ({part['ended']} at "
                f"{part['reached_s']:.1f} s): its figures cover the parts it flew"
            )
        else:
            notes.append(
                f"{agent} did not complete the run ({part['ended']} at run time "
                f"{part['reached_s']:.1f} s): its figures cover that part only"
            )
    return notes


def _spans(spans: list[list[float]]) -> str:
    """``[[6.1, 8.4], [12, 13]]`` -> ``6.1 to 8.4, 12.0 to 13.0``."""
    return ", ".join(f"{a:.1f} to {b:.1f}" for a, b in spans)


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
        holes = entry.get("gaps_s") or []
        flown = (
            f" in {len(entry.get('segments_s') or [])} segments, gap {_spans(holes)} s"
            if holes
            else ""
        )
        stood = "".join(
            f", stand-in {holder} {a:.1f} to {b:.1f} s"
            for a, b, holder in entry.get("stand_in_s") or []
        )
        lines.append(f"{agent}: {shown}, {_how(entry)}{flown}{stood}")
    return lines

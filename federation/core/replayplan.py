"""A replay's decisions, free of I/O (``fedlab replay``): whether a recorded agent may be
replayed under a name, which live run it plays against, and which recorded pose is due
at a run time. Time is passed in; nothing here reads a clock or opens a session.

Refusals are one table, :data:`REFUSALS`; every row that applies is said (exit code 2):

=======================  =================================================================
row                      refused when
=======================  =================================================================
name_live                an agent's liveliness token is present on the target name
own_name_real            the recording is of a real (hardware) platform and the target
                         name is the recorded one
own_name_unknown         the recorded platform is unknown (not in the file, or a kind
                         not installed here) and the target name is the recorded one
target_real              the target name's own platform (its config, or its status in
                         the file) is a real one
target_unknown           ``--as`` names a config whose platform kind is not installed
=======================  =================================================================

A replay plays against the live run the other agents announce in their status
(:class:`RunWatch`): run time is ``t_ref - start_at - frozen_total`` on the run's
reference clock; a frozen run pauses it, an aborted or finished one ends it.
:class:`ReplayPlan` walks the recorded poses in run-time order (an iterator: a
recording is never loaded whole) and gives, at run time ``t``, the latest pose recorded
at or before ``t`` not given yet; older ones not given are skipped (a pose late is a
pose that misleads a follower's latency compensation).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from federation.core.wire import Pose

__all__ = [
    "REFUSALS",
    "LiveRun",
    "RecordedPose",
    "ReplayPlan",
    "RunWatch",
    "Target",
    "refusals",
]


@dataclass(frozen=True)
class Target:
    """What the refusal rules look at.

    ``recorded_hardware`` / ``target_hardware``: True a real platform, False a
    simulated one, None unknown (``target_hardware`` None also when nothing is known
    of the target name, which is then judged by the recording alone)."""

    recorded: str
    target: str
    live: bool
    recorded_hardware: bool | None
    target_hardware: bool | None = None
    target_known: bool = True

    @property
    def own_name(self) -> bool:
        return self.target == self.recorded


REFUSALS: tuple[tuple[str, Callable[[Target], bool], str], ...] = (
    (
        "name_live",
        lambda t: t.live,
        "an agent named {target} is live in the federation: replay --as another name",
    ),
    (
        "own_name_real",
        lambda t: t.own_name and t.recorded_hardware is True,
        "{recorded} flew a real platform: its identity is never replayed "
        "(replay it --as a simulated agent's name)",
    ),
    (
        "own_name_unknown",
        lambda t: t.own_name and t.recorded_hardware is None,
        "{recorded}'s platform is not known from the recording: it may be a real one, "
        "so its identity is not replayed (replay it --as a simulated agent's name)",
    ),
    (
        "target_real",
        lambda t: t.target_hardware is True,
        "{target} is a real platform's name: a replay never takes it",
    ),
    (
        "target_unknown",
        lambda t: not t.target_known,
        "{target}'s platform kind is not known here: it may be a real one, so a replay "
        "does not take its name",
    ),
)
"""(row, applies, message): every row that applies refuses the replay."""


def refusals(target: Target) -> list[tuple[str, str]]:
    """Every refusal row that applies to ``target``: (row, message); empty: allowed."""
    fields = {"recorded": target.recorded, "target": target.target}
    return [(row, text.format(**fields)) for row, applies, text in REFUSALS if applies(target)]


class RecordedPose(NamedTuple):
    """A recorded pose at its recorded run time (s)."""

    run_time: float
    pose: Pose


class ReplayPlan:
    """The recorded poses, in run-time order, given out as run time passes."""

    def __init__(self, poses: Iterable[RecordedPose]):
        self._poses: Iterator[RecordedPose] = iter(poses)
        self._next: RecordedPose | None = next(self._poses, None)
        self.given = 0
        self.skipped = 0
        self.last_run_time: float | None = None  # recorded run time of the last given

    @property
    def finished(self) -> bool:
        """Every pose given or skipped: the recording has ended."""
        return self._next is None

    @property
    def next_due(self) -> float | None:
        """Recorded run time of the next pose (None: finished)."""
        return None if self._next is None else self._next.run_time

    def _advance(self) -> RecordedPose:
        assert self._next is not None
        current = self._next
        following = next(self._poses, None)
        if following is not None and following.run_time < current.run_time:
            raise ValueError(
                f"recorded poses out of run-time order: {following.run_time} after "
                f"{current.run_time}"
            )
        self._next = following
        return current

    def skip_to(self, run_time: float) -> int:
        """Skip every pose recorded before ``run_time`` (a run joined under way);
        how many were skipped."""
        count = 0
        while self._next is not None and self._next.run_time < run_time:
            self._advance()
            count += 1
        self.skipped += count
        return count

    def due(self, run_time: float) -> RecordedPose | None:
        """The latest pose recorded at or before ``run_time`` not given yet (None: none
        is due); the older ones not given are skipped."""
        latest: RecordedPose | None = None
        while self._next is not None and self._next.run_time <= run_time:
            if latest is not None:
                self.skipped += 1
            latest = self._advance()
        if latest is not None:
            self.given += 1
            self.last_run_time = latest.run_time
        return latest


class LiveRun(NamedTuple):
    """A run under way as an agent's status announces it."""

    run_id: str
    start_at: float  # on the reference clock, s
    frozen_total: float  # reference time spent frozen, s
    mode: str  # armed, running, frozen, done, aborted
    reference: str  # LAB/NAME whose clock start_at is on
    agent: str  # who announced it

    def run_time(self, t_ref: float) -> float | None:
        """Run time at reference time ``t_ref`` (None: not playing: frozen, ended)."""
        if self.mode not in ("armed", "running"):
            return None
        return t_ref - self.start_at - self.frozen_total


_UNDER_WAY = ("armed", "running", "frozen")
_ENDED = ("aborted", "done")


class RunWatch:
    """The live run a replay plays against, from the other agents' statuses.

    The first run announced (armed, running or frozen, with a start instant and a
    reference) is the run; the replay's own name and other replays' statuses are not
    heard. The run ends when an agent that announced it reports it aborted or done."""

    def __init__(self, own: str):
        self.own = own
        self.run: LiveRun | None = None
        self.ended: str | None = None  # why the run ended (None: it has not)
        self._announcers: dict[str, LiveRun] = {}

    def observe(self, agent: str, status: Mapping[str, Any]) -> None:
        """One status of ``agent`` (a dict as :class:`schemas.messages.Status` dumps)."""
        if agent == self.own or status.get("replay") is not None or self.ended:
            return
        run_id, start_at = status.get("run_id"), status.get("start_at")
        mode, reference = str(status.get("mode")), status.get("reference")
        if not isinstance(run_id, str) or not isinstance(reference, str):
            return
        if self.run is not None and run_id != self.run.run_id:
            return
        if mode in _ENDED and self.run is not None and agent in self._announcers:
            self.ended = f"{agent} reports run {run_id} {mode}"
            return
        if mode not in _UNDER_WAY or not isinstance(start_at, (int, float)):
            return
        frozen = status.get("frozen_total")
        seen = LiveRun(
            run_id, float(start_at), float(frozen) if isinstance(frozen, (int, float)) else 0.0,
            mode, reference, agent,
        )  # fmt: skip
        self._announcers[agent] = seen
        self.run = seen

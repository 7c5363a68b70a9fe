"""Reading a run directory: every agent's MCAP recording and the demo's ``run.json``.

A run directory holds one MCAP recording per agent (``<lab>-<name>.mcap``, see
:mod:`federation.runtime.recorder`), one more per segment an agent flew after a rejoin
(``<lab>-<name>.seg2.mcap``...: read as that agent's, in segment order) and,
optionally, the ``run.json`` the demo writes (roles, followed agents, latency
compensation, the emulated link). A damaged
recording (an agent killed, its summary broken) gives every message up to the
damage; what could not be read becomes a note, not an error. Recordings from before
the channels in Foxglove's types (``/tf``, ``/pose``) read the same: only the JSON
channels are read. A merged file (``fedlab merge``, its ``fedlab.merge`` metadata
record) in the folder is not a recording and is skipped here:
:mod:`federation.report.frommerged` reads it into the same :class:`Run`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from federation.core.channels import Channel
from federation.runtime.mcapfile import is_finished
from federation.runtime.recorder import read_messages, read_metadata
from schemas.config import ConfigError

__all__ = [
    "MERGE_METADATA",
    "AgentRecording",
    "Messages",
    "Run",
    "add_recording",
    "agent_from_filename",
    "is_merged",
    "load_run",
    "parse_meta",
    "recordings",
    "segment_of",
]

MERGE_METADATA = "fedlab.merge"
"""Name of a merged file's metadata record (:mod:`federation.report.merge`): the mark
that tells a merged file from a recording."""

Messages = dict[str, list[dict[str, Any]]]
"""A recording's decoded messages by channel, in log-time order."""


@dataclass
class AgentRecording:
    """One agent's decoded recording and what is known of its part in the run."""

    agent: str
    messages: Messages
    """Every segment's messages, one after the other."""
    file: str = ""
    role: str | None = None
    follow: str | None = None
    platform: str | None = None
    latency_compensation: bool | None = None
    segments: list[Messages] = field(default_factory=list)
    """Each segment's messages (one file each: the run from its start, then from each
    rejoin), in order; one for an agent that flew its run in one go."""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    """Its first segment's MCAP metadata records by name (``fedlab.run``...; empty for
    an old or damaged recording)."""

    def channel(self, topic: str) -> list[dict[str, Any]]:
        return self.messages.get(topic) or []

    def add_segment(self, messages: Messages, file: str) -> None:
        """The next segment of its run (flown after a rejoin), recorded in ``file``."""
        self.segments.append(messages)
        for topic, items in messages.items():
            self.messages[topic] = [*self.channel(topic), *items]
        self.file = f"{self.file}, {file}" if self.file else file


def segment_of(path: Path) -> int:
    """``rome-pinocchio.seg2.mcap`` -> 2; a run's first recording (no ``.segN``) -> 1."""
    _, _, tail = path.stem.rpartition(".seg")
    return int(tail) if path.stem != tail and tail.isdigit() else 1


@dataclass
class Run:
    """Every agent's recording, the demo's ``run.json`` (or None) and what was missing."""

    agents: dict[str, AgentRecording]
    meta: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
    directory: str = ""
    sources: list[str] = field(default_factory=list)
    """The files read, by name: the per-agent recordings, or the one merged file."""
    from_merged: bool = False
    """Whether it was read from a merged file (:mod:`federation.report.frommerged`)."""
    experiment_json: str | None = None
    """The run's ``experiment.json``'s text as a merged file carries it (None: read
    from ``directory``, if there)."""

    @property
    def leader(self) -> str | None:
        if self.meta and isinstance(self.meta.get("leader"), str):
            return str(self.meta["leader"])
        leaders = [a for a, r in self.agents.items() if r.role == "leader"]
        return leaders[0] if leaders else None

    @property
    def emulated_delay_s(self) -> float | None:
        return self._link_ms("delay_ms")

    @property
    def emulated_jitter_s(self) -> float | None:
        return self._link_ms("jitter_ms")

    def _link_ms(self, key: str) -> float | None:
        """A figure of the emulated link in run.json (ms), in seconds."""
        link = (self.meta or {}).get("link")
        if isinstance(link, dict) and link.get(key) is not None:
            return float(link[key]) / 1e3
        return None


def agent_from_filename(path: Path) -> str:
    """``rome-pinocchio-raw.mcap`` -> ``rome/pinocchio-raw`` (lab names hold no dash;
    ``rome-pinocchio.seg2.mcap``, a later segment, -> ``rome/pinocchio``)."""
    stem = path.stem if segment_of(path) == 1 else path.stem.rpartition(".seg")[0]
    lab, _, name = stem.partition("-")
    return f"{lab}/{name}" if name else lab


def _read(path: Path) -> tuple[Messages | None, str | None]:
    """A recording's messages and a note; from a damaged file (agent killed, or its
    summary broken), every message up to the damage."""
    try:
        return read_messages(path), None
    except Exception as error:  # mcap raises many kinds on a truncated or foreign file
        partial = _recover(path)
        count = sum(len(v) for v in partial.values())
        if not count:
            return None, f"{path.name}: unreadable ({type(error).__name__}: {error}); skipped"
        return partial, f"{path.name}: damaged or unfinished recording; {count} messages recovered"


def _recover(path: Path) -> Messages:
    """Every message read record by record up to the damage, by channel, in log-time
    order; empty if a message there is not JSON."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics: dict[int, str] = {}
    stamped: dict[str, list[tuple[int, bytes]]] = {}
    try:
        with path.open("rb") as f:
            for record in StreamReader(f).records:
                if isinstance(record, Channel) and record.message_encoding == "json":
                    topics[record.id] = record.topic  # Foxglove's types (/tf, /pose) skipped
                elif isinstance(record, Message) and record.channel_id in topics:
                    topic = topics[record.channel_id]
                    stamped.setdefault(topic, []).append((record.log_time, record.data))
    except Exception:  # the damaged part: keep what came before it
        pass
    partial: Messages = {}
    try:
        for topic, items in stamped.items():
            items.sort(key=lambda item: item[0])
            partial[topic] = [json.loads(data) for _, data in items]
    except ValueError:
        return {}
    return partial


def is_merged(path: Path) -> bool:
    """Whether ``path`` is a merged file (its ``fedlab.merge`` record), not a recording."""
    if not is_finished(path):
        return False
    return MERGE_METADATA in read_metadata(path)


def recordings(directory: Path) -> list[Path]:
    """The per-agent recordings of a run folder (merged files left out), by agent and
    segment."""
    files = [p for p in directory.glob("*.mcap") if not is_merged(p)]
    return sorted(files, key=lambda p: (agent_from_filename(p), segment_of(p)))


def load_run(run_dir: str | Path) -> Run:
    """Read every per-agent ``*.mcap`` of ``run_dir`` and its optional ``run.json``.

    Raises
    ------
    ConfigError
        When the directory is missing or holds no readable recording.
    """
    directory = Path(run_dir)
    if not directory.is_dir():
        raise ConfigError(f"{directory}: no such run directory")
    files = recordings(directory)
    if not files:
        raise ConfigError(f"{directory}: no MCAP recordings (*.mcap) in this run directory")
    notes: list[str] = []
    meta = _read_meta(directory / "run.json", notes)
    agents: dict[str, AgentRecording] = {}
    for path in files:
        messages, note = _read(path)
        if note:
            notes.append(note)
        if messages is None:
            continue
        status = messages.get(Channel.STATUS) or []
        agent = str(status[0].get("agent")) if status else agent_from_filename(path)
        add_recording(
            agents, agent, messages, path.name, segment_of(path), _metadata(path), meta, notes
        )
    if not agents:
        raise ConfigError(f"{directory}: no readable MCAP recording ({len(files)} files tried)")
    for agent in (meta or {}).get("agents") or {}:
        if agent not in agents:
            notes.append(f"{agent} is in run.json but has no recording")
    return Run(agents, meta, notes, str(directory), [p.name for p in files])


def add_recording(
    agents: dict[str, AgentRecording],
    agent: str,
    messages: Messages,
    file: str,
    segment: int,
    metadata: dict[str, dict[str, str]],
    meta: dict[str, Any] | None,
    notes: list[str],
) -> None:
    """``agent``'s recording ``file`` (its ``segment``, 1 for a run's first): its first,
    a later segment of its run, or a second recording of it (skipped, with a note)."""
    rec = agents.get(agent)
    if rec is None:
        agents[agent] = rec = _describe(agent, messages, file, meta)
        rec.metadata = metadata
    elif segment > len(rec.segments):
        rec.add_segment(messages, file)
    else:
        notes.append(f"{file}: a second recording of {agent}; skipped")


def _metadata(path: Path) -> dict[str, dict[str, str]]:
    """A recording's metadata records; none for an old or damaged one."""
    try:
        return read_metadata(path)
    except Exception:  # mcap raises many kinds on a cut file
        return {}


def _read_meta(run_json: Path, notes: list[str]) -> dict[str, Any] | None:
    """The demo's run.json as a dict; None (and a note) if missing or unreadable."""
    if not run_json.exists():
        return parse_meta(None, notes)
    try:
        text = run_json.read_text(encoding="utf-8")
    except OSError as error:
        notes.append(f"run.json unreadable ({error}); ignored")
        return None
    return parse_meta(text, notes)


def parse_meta(text: str | None, notes: list[str]) -> dict[str, Any] | None:
    """run.json's text as a dict; None (and a note) if missing (``None``) or not a JSON
    object."""
    if text is None:
        notes.append("no run.json: roles from the recordings, no emulated link to compare with")
        return None
    try:
        loaded = json.loads(text)
    except json.JSONDecodeError as error:
        notes.append(f"run.json unreadable ({error}); ignored")
        return None
    if not isinstance(loaded, dict):
        notes.append("run.json is not a JSON object; ignored")
        return None
    return loaded


def _describe(
    agent: str, messages: Messages, file: str, meta: dict[str, Any] | None
) -> AgentRecording:
    """Role and followed agent from run.json, else from the recorded status."""
    rec = AgentRecording(
        agent, {k: list(v) for k, v in messages.items()}, file, segments=[messages]
    )
    status = messages.get(Channel.STATUS) or []
    last = status[-1] if status else {}
    info = ((meta or {}).get("agents") or {}).get(agent) or {}
    rec.role = info.get("role") or last.get("role")
    rec.follow = info.get("follow") or last.get("follow")
    rec.platform = info.get("platform") or last.get("platform")
    comp = info.get("latency_compensation")
    rec.latency_compensation = None if comp is None else bool(comp)
    received = [str(m.get("agent")) for m in messages.get(Channel.POSE_RECEIVED) or []]
    if received and rec.role in (None, "follower") and rec.follow is None:
        # Whose poses it received most: the agent it followed.
        rec.role, rec.follow = "follower", max(set(received), key=received.count)
    return rec

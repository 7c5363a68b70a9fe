"""Reading a run from its merged file (``fedlab merge``), and choosing the report's source.

:func:`load_merged` gives the same :class:`~federation.report.load.Run` from a merged
file that :func:`~federation.report.load.load_run` gives from the per-agent recordings
it was merged from, message for message, so every figure, ``summary.json`` and the
merged file come from one source. It rebuilds each recording as
:mod:`federation.report.merge` describes:

- a recorded channel is one whose metadata names its ``agent``, ``source_topic`` and
  ``segment`` (the channels in Foxglove's types and the clock and peer views name no
  ``source_topic`` and are not read);
- each JSON message loses its two last fields, ``t_ref`` and ``t_ref_bound``;
- a channel's messages are put back in the recording's log-time order by their publish
  time (the recording's log time), ties in the merged file's order;
- each agent's metadata records are the merged file's ``LAB/NAME RECORD`` ones, run.json
  and experiment.json the merged file's records of those names.

:func:`open_run` picks the source: a merged file named, else the run folder's merged
file if there is one and it was merged from the recordings the folder holds now (every
recording's name and size), else the recordings. An agent the merge left out (no
estimate of the reference clock) is in a note.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from mcap.reader import make_reader

from federation.core.channels import Channel
from federation.report.load import (
    MERGE_METADATA,
    AgentRecording,
    Messages,
    Run,
    add_recording,
    agent_from_filename,
    is_merged,
    load_run,
    parse_meta,
    recordings,
)
from federation.runtime.mcapfile import is_finished
from schemas.config import ConfigError

__all__ = ["DEFAULT_NAME", "Source", "find_merged", "load_merged", "open_run", "stale"]

DEFAULT_NAME = "merged.mcap"
"""The merged file's name in a run folder (``fedlab merge``'s and ``collect``'s default)."""
Source = Literal["auto", "merged", "recordings"]
"""Which files the report reads: the merged file if current (``auto``), the merged
file (``merged``), or the per-agent recordings (``recordings``)."""
_APPENDED = ("t_ref", "t_ref_bound")


@dataclass
class _Part:
    """One recording (an agent's segment) as the merged file holds it."""

    agent: str
    file: str
    segment: int
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    stamped: dict[str, list[tuple[int, int, Any]]] = field(default_factory=dict)

    def messages(self) -> Messages:
        """By channel, in the recording's log-time order (its publish time in the merged
        file; ties in file order), every channel the recorder knows listed."""
        out: Messages = {str(t): [] for t in Channel}
        for topic, items in self.stamped.items():
            items.sort(key=lambda item: (item[0], item[1]))
            out[topic] = [data for _, _, data in items]
        return out


def _original(data: bytes) -> Any:
    """A merged JSON message as its recording had it: ``t_ref``, ``t_ref_bound`` off."""
    decoded = json.loads(data)
    if isinstance(decoded, dict) and list(decoded)[-2:] == list(_APPENDED):
        for key in _APPENDED:
            del decoded[key]
    return decoded


def _records(metadata: dict[str, dict[str, str]]) -> dict[str, dict[str, dict[str, str]]]:
    """The merged file's per-recording records by label (``LAB/NAME``, ``LAB/NAME.segN``)."""
    out: dict[str, dict[str, dict[str, str]]] = {}
    for name, record in metadata.items():
        label, sep, record_name = name.partition(" ")
        if sep and "/" in label:
            out.setdefault(label, {})[record_name] = record
    return out


def _read(path: Path) -> tuple[dict[str, dict[str, str]], dict[tuple[str, int], _Part]]:
    """The merged file's metadata and each recording's messages."""
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    if not is_finished(path):
        raise ConfigError(
            f"{path}: not a finished MCAP file (cut short, or not MCAP): merge the run again"
        )
    parts: dict[tuple[str, int], _Part] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        if MERGE_METADATA not in metadata:
            raise ConfigError(
                f"{path}: not a merged run (no {MERGE_METADATA} metadata record); "
                "give the run folder to read its recordings"
            )
        for order, (_s, channel, message) in enumerate(reader.iter_messages(log_time_order=False)):
            meta = channel.metadata
            if channel.message_encoding != "json" or "source_topic" not in meta:
                continue
            try:
                segment = int(meta.get("segment", "1"))
                key = (meta["agent"], segment)
                data = _original(message.data)
            except (KeyError, ValueError) as error:
                raise ConfigError(
                    f"{path}: channel {channel.topic}: unreadable message or channel metadata "
                    f"({type(error).__name__}: {error})"
                ) from None
            part = parts.get(key)
            if part is None:
                part = parts[key] = _Part(key[0], meta.get("source_file", ""), segment)
            stamped = part.stamped.setdefault(meta["source_topic"], [])
            stamped.append((message.publish_time, order, data))
    return metadata, parts


def load_merged(path: str | Path) -> Run:
    """The run a merged file holds, as :func:`~federation.report.load.load_run` reads it
    from the recordings it was merged from.

    Raises
    ------
    ConfigError
        When the file is missing, cut short, not a merged run or holds no recording.
    """
    path = Path(path)
    metadata, parts = _read(path)
    notes: list[str] = []
    run_json = metadata.get("run.json", {}).get("json")
    meta = parse_meta(run_json, notes)
    records = _records(metadata)
    for label, recs in records.items():
        clock = recs.get("clock") or {}
        if clock.get("source") == "none":
            notes.append(
                f"{clock.get('file') or label}: not in the merged file (no estimate of the "
                "reference clock to place it by): its figures need the recordings "
                "(fedlab report RUN_DIR --source recordings)"
            )
    agents: dict[str, AgentRecording] = {}
    for part in sorted(
        parts.values(), key=lambda p: (agent_from_filename(Path(p.file)), p.segment)
    ):
        label = part.agent if part.segment == 1 else f"{part.agent}.seg{part.segment}"
        own = {k: v for k, v in records.get(label, {}).items() if k != "clock"}
        add_recording(
            agents, part.agent, part.messages(), part.file, part.segment, own, meta, notes
        )
    if not agents:
        raise ConfigError(f"{path}: the merged file holds no agent's recording")
    for agent in (meta or {}).get("agents") or {}:
        if agent not in agents:
            notes.append(f"{agent} is in run.json but has no recording")
    experiment = metadata.get("experiment.json", {}).get("json")
    return Run(
        agents, meta, notes, str(path.parent), [path.name], from_merged=True,
        experiment_json=experiment,
    )  # fmt: skip


def find_merged(directory: Path) -> Path | None:
    """The run folder's merged file: ``merged.mcap``, else its one merged file; None if
    it has none.

    Raises
    ------
    ConfigError
        When it holds several merged files and none is ``merged.mcap``.
    """
    default = directory / DEFAULT_NAME
    if default.is_file() and is_merged(default):
        return default
    found = sorted(p for p in directory.glob("*.mcap") if is_merged(p))
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise ConfigError(f"{directory}: several merged files ({names}): name the one to read")
    return found[0] if found else None


def stale(merged: Path, directory: Path) -> list[str]:
    """How the recordings in ``directory`` differ from those ``merged`` was made of
    (a recording added, missing or of another size); empty when they are the same."""
    sources: dict[str, int | None] = {}
    with merged.open("rb") as f:
        for record in make_reader(f).iter_metadata():
            if record.name.endswith(" clock") and "file" in record.metadata:
                size = record.metadata.get("size_bytes")
                sources[record.metadata["file"]] = int(size) if size and size.isdigit() else None
    now = {p.name: p.stat().st_size for p in recordings(directory)}
    out = [f"{name} is not in it" for name in sorted(set(now) - set(sources))]
    out += [f"{name} is gone" for name in sorted(set(sources) - set(now))]
    out += [
        f"{name} has changed ({sources[name]} bytes merged, {size} now)"
        for name, size in sorted(now.items())
        if sources.get(name) is not None and sources[name] != size
    ]
    return out


def open_run(path: str | Path, source: Source = "auto") -> Run:
    """The run at ``path`` (a run folder or a merged file) from ``source``.

    ``auto``: a merged file named is read; in a run folder, its merged file if it was
    merged from the recordings there now, else the recordings (a note says why).

    Raises
    ------
    ConfigError
        When ``path`` is missing, ``source`` asks for files it lacks, or nothing reads.
    """
    path = Path(path)
    if path.is_file():
        if source == "recordings":
            raise ConfigError(f"{path}: a file; the recordings are read from their run folder")
        return load_merged(path)
    if not path.is_dir():
        raise ConfigError(f"{path}: no such run folder or merged file")
    merged = find_merged(path) if source != "recordings" else None
    if merged is None:
        if source == "merged":
            raise ConfigError(f"{path}: no merged file; write one with fedlab merge {path}")
        return load_run(path)
    differ = stale(merged, path) if source == "auto" else []
    if not differ:
        return load_merged(merged)
    run = load_run(path)
    run.notes.insert(
        0,
        f"{merged.name} was not merged from these recordings ({'; '.join(differ)}): read "
        f"the recordings; fedlab merge {path} brings it up to date",
    )
    return run

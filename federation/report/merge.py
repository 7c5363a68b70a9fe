"""One MCAP for a whole run, on reference time (``fedlab merge RUN_DIR``).

Each agent records its own file (:mod:`federation.runtime.recorder`): log times on its
host's wall clock, payload stamps on its own clock. :func:`merge` writes every agent's
channels into one file whose log time is the run's **reference time** (the reference
agent's clock, the one every follower's ``t_sim`` is on), never a host's wall clock:

.. math::

    \\text{log\\_time} = E + (t_\\text{ref} - T_0), \\qquad
    t_\\text{ref} = t + \\hat o(t)

with :math:`t` a message's stamp on its agent's clock (``t_exec``; ``t_recv`` for a
pose received, ``t3`` for a sync exchange), :math:`\\hat o(t)` the agent's own estimate
of the reference clock minus its own (``t_sim - t_exec`` of its ``/reference``,
linear between samples; 0 on the reference), :math:`T_0` the run's start on reference
time (the reference's ``started`` event) and :math:`E` that instant in UTC as the hosts'
wall clocks say it (the median over agents; its uncertainty is their disagreement plus
each one's scatter, in the ``fedlab.merge`` metadata record; it leaves out the
recorder's latency, the time from a stamp to its record, under a millisecond, which
makes :math:`E` late by as much). Each JSON message gains
two last fields, ``t_ref`` (s) and ``t_ref_bound`` (s, the error bound of its stamp:
its status lines' ``reference_bound`` plus its one-way delay to the reference, as its
pose stamps state it, the larger of those either side, plus the interpolation's; null
before its first estimate). The original log
time is each message's publish time and its sequence is kept, each agent's metadata
records are copied (named ``LAB/NAME RECORD``), and its clock is the channel
``/LAB/NAME/clock`` (a row at each point of the thinned estimate, ``point`` true, and
at each status line, each with its bound and the host truth where known) and a
summary in the metadata record ``LAB/NAME clock`` (its file, size, source, how many
points and status lines, the largest bound stated, the wall and host-truth lines):
the original files can be rebuilt from the merged one (drop the
two fields, log time from publish time, ``/tf`` and ``/pose`` again from
``/pose/sent``). Messages without an own-clock stamp (another program's channels) are
placed by their log time through the agent's wall-clock-to-own-clock line, whose
largest residual is added to their bound.

A later segment of an agent's run (``<lab>-<name>.seg2.mcap``..., recorded after a
rejoin, :mod:`federation.report.load`) is that agent's: its own clock map (the agent's
process started again), the same topic names on channels of their own whose metadata
says ``segment`` (and ``source_file``), its metadata records named
``LAB/NAME.segN RECORD``, and a Log line on ``/LAB/NAME/log`` at its first message
stating the gap since the segment before, on reference time.

Streaming, in a fixed memory: a first pass reads each file's ``/reference``,
``/status``, ``/control`` and ``/sync/exchange`` and writes the offset estimate thinned
(:class:`Thinned`: points only where a line through them would leave ``THIN_S``) and
each status line's own clock, bound, log time and host time to temporary files
(``mergeclock._Series``); the second reads every file once, in file order (the recorder
writes in log-time order; ordering by log time would load each file's chunk index,
megabytes), reads the estimate and the bounds back from those files a block at a time
in step with the messages, holds each agent's messages for ``REORDER_S`` (a message's
stamp precedes its log time by less) to order them by reference time, and merges the
agents with :func:`heapq.merge`. What is held is then the interpreter and its
libraries, per agent a window of ``REORDER_S`` of messages and two blocks of each
series, and the writer's chunk being built (``OUTPUT_CHUNK``). Two things still grow
with the run, both small: the writer's index of the chunks written (about 1.8 KiB a MiB
of output, written into the file's summary at its end), and, for a moment at the end of
each file's first pass, its status lines' own clock and times loaded for the wall-clock
line and the epoch's median (about 100 bytes a status line: 9 MiB for a day at one line
a second). Measured (``fedlab bench merge``, 4 agents): peaks of 81.0, 81.0, 82.5 and
86.3 MiB for 100, 300, 1,007 and 2,063 MiB of recordings, of which 62.3 MiB is the
interpreter and libraries; at 2 GiB the sampled memory rose 5 MiB across the second pass.

The first pass, each agent's clock and the epoch: :mod:`federation.report.mergeclock`.
Foxglove's types and the layout: :mod:`federation.report.mergeview`.
"""

from __future__ import annotations

import heapq
import itertools
import json
import math
import tomllib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np
from foxglove.messages import SceneUpdate
from mcap.exceptions import McapError
from mcap.records import Channel as McapChannel
from mcap.records import Header, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import Writer
from pydantic import ValidationError

from federation.core.channels import FOXGLOVE_CHANNELS, Channel
from federation.report import mergeview as view
from federation.report.analysis import clock_map
from federation.report.load import MERGE_METADATA
from federation.report.mergeclock import (
    STAMP_FIELDS,
    THIN_S,
    AgentClock,
    Epoch,
    Thinned,
    epoch,
    number,
    stream_messages,
    survey,
)
from federation.runtime.mcapfile import as_metadata
from federation.runtime.scene import corridor_entity
from schemas.config import ConfigError
from schemas.scenario import DockingConfig

__all__ = [
    "MERGE_METADATA",
    "REORDER_S",
    "STAMP_FIELDS",
    "THIN_S",
    "AgentClock",
    "MergeResult",
    "Thinned",
    "merge",
    "merge_folder",
    "survey",
    "write_merged",
]

# MERGE_METADATA (federation.report.load): the name of the merged file's metadata
# record: the epoch and its uncertainty, the reference agent, the run's start, what log
# and publish times mean, counts, notes.
MERGE_LIBRARY = "fedlab merge"  # the merged file's header's library: what marks it
OUTPUT_CHUNK = 4 * 2**20
"""Bytes (uncompressed) of a merged file's chunk. The writer keeps one index entry per
chunk (a few KiB with its channels' offsets) until it writes the summary: larger
chunks, fewer entries (about 1.8 KiB per MiB written: a chunk of 4 MiB is about 1 MiB
compressed, its entry 1.8 KiB with 36 channels)."""
REORDER_S = 2.0  # s a message is held to be ordered by reference time
_SOURCE_NOTES = {
    "none": "{}: no estimate of the reference clock; its messages left out",
    "exchanges": "{}: no /reference estimate; mapped by its sync exchanges",
}
_DERIVED = frozenset(FOXGLOVE_CHANNELS)  # a recording's /tf and /pose: from /pose/sent


@dataclass
class MergeResult:
    """What :func:`merge` wrote."""

    agents: list[str]
    reference: str | None
    epoch: Epoch
    messages_in: int = 0
    messages_out: int = 0
    late: int = 0  # written with a log time before one already written
    skipped: int = 0  # a recording's /tf and /pose (rebuilt from /pose/sent)
    notes: list[str] = field(default_factory=list)
    peer_topics: list[str] = field(default_factory=list)
    gaps: list[dict[str, Any]] = field(default_factory=list)  # between an agent's segments

    def metadata(self) -> dict[str, str]:
        return as_metadata({
            "format": "fedlab merged run 1", "reference_agent": self.reference,
            "agents": json.dumps(self.agents),
            "reference_start_s": repr(self.epoch.start), "epoch_ns": self.epoch.ns,
            "epoch_utc": _utc(self.epoch.ns) if self.epoch.hosts else None,
            "epoch_uncertainty_s": self.epoch.uncertainty,
            "host_wall_at_reference_zero_s": json.dumps(self.epoch.hosts),
            "log_time": "epoch_ns + (t_ref - reference_start_s) * 1e9: reference time",
            "publish_time": "the recording's log time: its host's wall clock",
            "appended_fields": "t_ref,t_ref_bound (s; the last two of each JSON message)",
            "messages_in": self.messages_in, "messages_out": self.messages_out,
            "late": self.late, "derived_skipped": self.skipped,
            "segment_gaps": json.dumps(self.gaps), "notes": json.dumps(self.notes),
        })  # fmt: skip


def _utc(ns: int) -> str:
    import datetime

    when = datetime.datetime.fromtimestamp(ns // 1_000_000_000, datetime.UTC)
    return when.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns % 1_000_000_000:09d}Z"


class _Item(NamedTuple):
    """One message to write, ordered by its log time (ns; then agent and sequence);
    or, with no channel, a point of the agent's offset estimate (``point``, own clock)."""

    ns: int
    agent: int
    seq: int
    channel: McapChannel | None
    schema: Schema | None
    message: McapMessage | None
    data: bytes
    decoded: dict[str, Any] | None
    point: float = math.nan


def _points(clock: AgentClock) -> Iterator[float]:
    """The own-clock times of the agent's offset estimate's points, in order."""
    if clock.estimate is None:
        return
    for columns in clock.estimate.rows():
        yield from columns[0].tolist()


def _mapped(clock: AgentClock, index: int, epoch: Epoch, notes: list[str]) -> Iterator[_Item]:
    """One agent's messages with their reference log time, ordered within ``REORDER_S``
    (its ``/tf`` and ``/pose`` left out and counted: ``/pose/sent`` gives them again),
    and its offset estimate's points, each once a message stamped at it or later is read
    (both read in step: the estimate from its temporary file)."""
    held: list[_Item] = []
    window = round(REORDER_S * 1e9)
    counter = itertools.count()
    points = _points(clock)
    upcoming = next(points, None)
    for schema, channel, message in stream_messages(clock.path, None, notes):
        if channel.topic in _DERIVED:
            clock.skipped += 1
            continue
        decoded = _decoded(channel, message)
        stamped = STAMP_FIELDS.get(channel.topic, "t_exec")
        t = None if decoded is None else number(decoded.get(stamped))
        extra, own = 0.0, t is not None
        if t is None:
            t, extra = clock.from_wall(message.log_time), clock.wall_residual
            if t is None:
                t, extra = clock.first or 0.0, math.inf
        while own and upcoming is not None and upcoming <= t:
            _push_point(held, clock, index, epoch, next(counter), upcoming)
            upcoming = next(points, None)
        t_ref = clock.to_reference(t)
        data = message.data
        if decoded is not None:
            bound = clock.bound(t)
            bound = None if bound is None or not math.isfinite(bound + extra) else bound + extra
            data = _appended(message.data, decoded, t_ref, bound)
        ns = epoch.log_time(t_ref)
        heapq.heappush(held, _Item(ns, index, next(counter), channel, schema, message, data,
                                   decoded))  # fmt: skip
        while held[0].ns <= ns - window:
            yield heapq.heappop(held)
    while upcoming is not None:
        _push_point(held, clock, index, epoch, next(counter), upcoming)
        upcoming = next(points, None)
    while held:
        yield heapq.heappop(held)


def _push_point(
    held: list[_Item], clock: AgentClock, index: int, epoch: Epoch, seq: int, t: float
) -> None:
    ns = epoch.log_time(clock.to_reference(t))
    heapq.heappush(held, _Item(ns, index, seq, None, None, None, b"", None, t))


def _decoded(channel: McapChannel, message: McapMessage) -> dict[str, Any] | None:
    """A JSON channel's message as a dict; None for any other."""
    if channel.message_encoding != "json":
        return None
    try:
        loaded = json.loads(message.data)
    except ValueError:
        return None
    return loaded if isinstance(loaded, dict) else None


def _appended(data: bytes, decoded: dict[str, Any], t_ref: float, bound: float | None) -> bytes:
    """A JSON object's bytes with ``t_ref`` and ``t_ref_bound`` as its last fields."""
    tail = f'"t_ref": {t_ref!r}, "t_ref_bound": {"null" if bound is None else repr(bound)}}}'
    body = data.rstrip()
    if not body.endswith(b"}"):
        return data
    return body[:-1] + (b", " if decoded else b"") + tail.encode()


class _Output:
    """The merged file's schemas and channels, each registered once."""

    def __init__(self, writer: Writer):
        self.writer = writer
        self.schemas: dict[Any, int] = {}
        self.channels: dict[Any, int] = {}  # by topic (or topic and segment)
        self.segment_end: dict[tuple[str, int], int] = {}  # (agent, segment): last log time
        self.last = -1
        self.late = 0
        self.written = 0
        self.docking: DockingConfig | None = None  # its corridor drawn with the target

    def schema(self, key: Any, name: str, encoding: str, data: bytes) -> int:
        if key not in self.schemas:
            self.schemas[key] = self.writer.register_schema(name, encoding, data)
        return self.schemas[key]

    def channel(
        self, topic: str, encoding: str, schema_id: int, meta: dict[str, str], key: Any = None
    ) -> int:
        key = topic if key is None else key
        if key not in self.channels:
            self.channels[key] = self.writer.register_channel(topic, encoding, schema_id, meta)
        return self.channels[key]

    def write(self, channel_id: int, ns: int, data: bytes, publish: int, seq: int = 0) -> None:
        if ns < self.last:
            self.late += 1
        self.last = max(self.last, ns)
        self.writer.add_message(channel_id, max(ns, 0), data, publish, seq)
        self.written += 1

    def foxglove(self, topic: str, message: Any, ns: int, publish: int, agent: str) -> None:
        """``message`` (a Foxglove type) on ``topic``, under the SDK's schema."""
        schema = type(message).get_schema()
        schema_id = self.schema(schema.name, schema.name, schema.encoding, schema.data)
        meta = {"agent": agent, "stamp_bound": "see t_ref_bound of /LAB/NAME/pose/sent"}
        channel = self.channel(topic, schema.encoding, schema_id, meta)
        self.write(channel, ns, message.encode(), publish)

    def json(self, topic: str, schema: dict[str, Any], row: Any, ns: int, publish: int) -> None:
        schema_id = self.schemas.get(schema["title"])
        if schema_id is None:
            schema_id = self.schema(schema["title"], schema["title"], "jsonschema",
                                    view.schema_json(schema))  # fmt: skip
        channel = self.channel(topic, "json", schema_id, {})
        self.write(channel, ns, json.dumps(row).encode(), publish)


def _source_schema(schema: Schema | None) -> tuple[str, str, bytes]:
    """A recorded channel's schema, a JSON schema given ``t_ref`` and ``t_ref_bound``."""
    if schema is None:
        return "", "", b""
    if schema.encoding != "jsonschema":
        return schema.name, schema.encoding, schema.data
    try:
        loaded = json.loads(schema.data)
    except ValueError:
        return schema.name, schema.encoding, schema.data
    properties = loaded.setdefault("properties", {})
    properties["t_ref"] = {"type": "number", "description": "reference time, s"}
    properties["t_ref_bound"] = {"type": ["number", "null"], "description": "its bound, s"}
    return schema.name, schema.encoding, json.dumps(loaded).encode()


def merge(
    paths: Sequence[Path],
    writer: Writer,
    run_json: str | None = None,
    experiment_json: str | None = None,
) -> MergeResult:
    """Merge the recordings ``paths`` (one per agent and segment) into ``writer``
    (started, not finished), on reference time (see the module's text); ``run.json``
    and ``experiment.json``'s text, if given, become metadata records of those names.

    Raises
    ------
    ConfigError
        When no recording names a reference agent, or none maps to it.
    """
    clocks: list[AgentClock] = []
    try:
        for p in paths:
            clocks.append(survey(Path(p)))
        return _merge(clocks, writer, run_json, experiment_json)
    finally:
        for c in clocks:
            c.close()


def _merge(
    clocks: list[AgentClock],
    writer: Writer,
    run_json: str | None,
    experiment_json: str | None,
) -> MergeResult:
    notes: list[str] = []
    for c in clocks:
        notes += c.notes
    named = Counter(c.reference for c in clocks if c.reference)
    reference = named.most_common(1)[0][0] if named else None
    if reference is None:
        raise ConfigError("no recording's status names the reference agent: nothing to map to")
    _truths(clocks, reference, notes)
    notes += [_SOURCE_NOTES[c.source].format(c.agent) for c in clocks if c.source in _SOURCE_NOTES]
    mapped = [c for c in clocks if c.source != "none"]
    if not mapped:
        raise ConfigError("no recording maps to reference time")
    when = epoch(mapped, notes)
    agents = list(dict.fromkeys(c.agent for c in mapped))  # an agent's segments: one
    result = MergeResult(agents, reference, when, notes=notes)
    for c in clocks:
        writer.add_metadata(f"{c.label} clock", as_metadata(c.describe()))
        for name, record in c.metadata.items():
            writer.add_metadata(f"{c.label} {name}", record)
    if run_json is not None:
        writer.add_metadata("run.json", {"json": run_json})
    if experiment_json is not None:
        writer.add_metadata("experiment.json", {"json": experiment_json})
    out = _Output(writer)
    out.docking = _docking(clocks, experiment_json, notes)
    before: dict[str, dict[str, Any]] = {}
    streams = [_mapped(c, i, when, notes) for i, c in enumerate(mapped)]
    for item in heapq.merge(*streams):
        result.messages_in += item.channel is not None  # a point of an estimate: not read
        _write(out, mapped[item.agent], item, before, result)
    result.messages_out, result.late = out.written, out.late
    result.skipped = sum(c.skipped for c in mapped)
    result.messages_in += result.skipped
    for gap in result.gaps:
        notes.append(
            f"{gap['agent']}: segment {gap['segment']} ({gap['file']}) begins after a gap of "
            f"{gap['gap_s']:.3f} s on reference time with no recording"
        )
    writer.add_metadata(MERGE_METADATA, result.metadata())
    return result


def _docking(
    clocks: Sequence[AgentClock], experiment_json: str | None, notes: list[str]
) -> DockingConfig | None:
    """The run's ``[docking]`` table, if its experiment is a docking one: from the folder's
    ``experiment.json``, else from the experiment file each recording carries (its
    ``fedlab.run`` metadata). One that does not load is noted and nothing is drawn."""
    texts: list[tuple[str, str, Callable[[str], Any]]] = []
    if experiment_json:
        texts.append(("experiment.json", experiment_json, json.loads))
    for c in clocks:  # every agent's recording carries the same file: each text once
        text = (c.metadata.get("fedlab.run") or {}).get("experiment")
        if text and not text.startswith("unreadable") and text not in {t for _, t, _ in texts}:
            texts.append((f"{c.label}'s recorded experiment", text, tomllib.loads))
    for where, text, parse in texts:
        try:
            spec = parse(text)
            if not isinstance(spec, dict) or spec.get("kind") != "docking":
                continue
            return DockingConfig.model_validate(spec.get("docking"))
        except ValidationError as error:
            e = error.errors()[0]
            field = ".".join(["docking", *map(str, e["loc"])])
            notes.append(f"{where}: its [docking] table does not load ({field}: {e['msg']}): "
                         "no corridor drawn")  # fmt: skip
        except ValueError as error:  # JSON and TOML errors
            first = str(error).splitlines()[0]
            notes.append(f"{where}: does not parse ({first}): no corridor drawn")
    return None


def _truths(clocks: Sequence[AgentClock], reference: str, notes: list[str]) -> None:
    """Keep each agent's host truth only when every recording comes from one host (their
    monotonic clocks are then one), as the report assumes."""
    hosts = {c.host for c in clocks}
    ref = next((c for c in clocks if c.agent == reference), None)
    if len(hosts) > 1 or ref is None or ref.truth is None:
        for c in clocks:
            c.truth = None
        notes.append("no host truth: the recordings come from several hosts or lack the reference")
        return
    for c in clocks:
        c.reference_truth = ref.truth


def _true_offset(clock: AgentClock, t: float) -> float | None:
    """Reference minus own clock at own time ``t`` by the host truth, if known."""
    if clock.truth is None or clock.reference_truth is None:
        return None
    return float(clock_map(clock.truth, clock.reference_truth)(np.array([t]))[0]) - t


def _write(
    out: _Output,
    clock: AgentClock,
    item: _Item,
    before: dict[str, dict[str, Any]],
    result: MergeResult,
) -> None:
    """One recorded message, namespaced, and what Foxglove shows of it; or a point of
    the agent's offset estimate, as a clock row."""
    if item.channel is None or item.message is None:
        _clock_row(out, clock, item.point, item.ns, item.ns, point=True)
        return
    agent, topic, ns = clock.agent, item.channel.topic, item.ns
    publish, decoded = item.message.log_time, item.decoded
    if (agent, clock.segment) not in out.segment_end:
        _segment_begins(out, clock, ns, publish, result)
    out.segment_end[(agent, clock.segment)] = ns
    key = (f"/{agent}{topic}", clock.segment)
    channel = out.channels.get(key)
    if channel is None:
        channel = _register(out, clock, item)
    out.write(channel, ns, item.data, publish, item.message.sequence)
    if decoded is None:
        return
    if topic == Channel.POSE_SENT:
        shown = view.pose_messages(agent, decoded, ns)
        if shown is not None:
            out.foxglove("/tf", shown[0], ns, publish, agent)
            out.foxglove(f"/{agent}/pose", shown[1], ns, publish, agent)
    elif topic == Channel.CONTROL:
        out.foxglove(f"/{agent}/log", view.control_log(agent, decoded, ns), ns, publish, agent)
    elif topic == Channel.STATUS:
        _write_status(out, clock, decoded, ns, publish, before, result)


def _register(out: _Output, clock: AgentClock, item: _Item) -> int:
    """A recorded channel's channel (and schema) in the merged file: its topic under the
    agent's name, its metadata saying whose, from which file and stamped how."""
    assert item.channel is not None
    agent, topic = clock.agent, item.channel.topic
    schema_id = out.schemas.get((agent, item.channel.schema_id))
    if schema_id is None:
        name, encoding, data = _source_schema(item.schema)
        schema_id = out.schema((agent, item.channel.schema_id), name, encoding, data) if name else 0
    meta = dict(item.channel.metadata) | {
        "agent": agent, "source_topic": topic, "segment": str(clock.segment),
        "stamp_field": STAMP_FIELDS.get(topic, "t_exec"), "source_file": clock.path.name,
    }  # fmt: skip
    return out.channel(
        f"/{agent}{topic}", item.channel.message_encoding, schema_id, meta,
        key=(f"/{agent}{topic}", clock.segment),
    )  # fmt: skip


def _segment_begins(
    out: _Output, clock: AgentClock, ns: int, publish: int, result: MergeResult
) -> None:
    """A later segment's first message: a Log line on the gap since the segment before
    (reference time, s), and the gap in the result."""
    if clock.segment == 1:
        return
    ends = [
        end for (a, k), end in out.segment_end.items() if a == clock.agent and k < clock.segment
    ]
    gap = (ns - max(ends)) / 1e9 if ends else None
    result.gaps.append({
        "agent": clock.agent, "segment": clock.segment, "file": clock.path.name,
        "from_log_time_ns": max(ends) if ends else None, "to_log_time_ns": ns, "gap_s": gap,
    })  # fmt: skip
    text = (
        f"segment {clock.segment} ({clock.path.name}) begins: no recording for "
        + ("an unknown time" if gap is None else f"{gap:.3f} s")
        + " since the segment before (the agent rejoined)"
    )
    out.foxglove(f"/{clock.agent}/log", view.log(clock.agent, ns, text, warning=True), ns,
                 publish, clock.agent)  # fmt: skip


def _write_status(
    out: _Output,
    clock: AgentClock,
    decoded: dict[str, Any],
    ns: int,
    publish: int,
    before: dict[str, dict[str, Any]],
    result: MergeResult,
) -> None:
    """A status line's log lines, scene, lab frame, clock row and peer views."""
    agent = clock.agent
    lines, entities, frame = view.status_view(agent, decoded, before.get(agent), ns)
    before[agent] = {"hold": decoded.get("hold"), "peers": decoded.get("peers")}
    for line in lines:
        out.foxglove(f"/{agent}/log", line, ns, publish, agent)
    if out.docking is not None and agent == out.docking.target:
        entities.append(corridor_entity(out.docking, ns))
    out.foxglove("/scene", SceneUpdate(entities=entities), ns, publish, agent)
    if frame is not None:
        out.foxglove("/tf", frame, ns, publish, agent)
    t = number(decoded.get("t_exec"))
    if t is not None:
        _clock_row(out, clock, t, ns, publish, point=False)
    for peer, row in view.peer_rows(decoded):
        topic_name = f"/{agent}/sync/{peer}"
        if topic_name not in out.channels:
            result.peer_topics.append(topic_name)
        out.json(topic_name, view.PEER_SCHEMA, row, ns, publish)


def _clock_row(
    out: _Output, clock: AgentClock, t: float, ns: int, publish: int, point: bool
) -> None:
    """A ``/LAB/NAME/clock`` row at own clock ``t``: a point of the estimate, or a status
    line's."""
    row = view.clock_row(
        t, clock.to_reference(t), clock.bound(t), _true_offset(clock, t), point=point
    )
    out.json(f"/{clock.agent}/clock", view.CLOCK_SCHEMA, row, ns, publish)


def write_merged(run_dir: str | Path, out: str | Path | None = None) -> tuple[MergeResult, Path]:
    """Merge every ``*.mcap`` of ``run_dir`` into ``out`` (default ``RUN_DIR/merged.mcap``,
    itself never read as a recording) and write its Foxglove layout beside it
    (``NAME.layout.json``). Returns the result and the layout's path.

    Raises
    ------
    ConfigError
        When the directory holds no recording, or none maps to reference time.
    """
    directory = Path(run_dir)
    if not directory.is_dir():
        raise ConfigError(f"{directory}: no such run directory")
    target = Path(out) if out is not None else directory / "merged.mcap"
    paths = [p for p in sorted(directory.glob("*.mcap")) if p.resolve() != target.resolve()]
    paths = [p for p in paths if not _is_merged(p)]
    if not paths:
        raise ConfigError(f"{directory}: no MCAP recordings (*.mcap) in this run directory")
    texts = [_text(directory / name) for name in ("run.json", "experiment.json")]
    partial = target.with_name(target.name + ".partial")
    try:
        with partial.open("wb") as sink:
            result = _write_file(paths, sink, *texts)
    except BaseException:  # no half-written file left; the recordings are untouched
        partial.unlink(missing_ok=True)
        raise
    partial.replace(target)
    layout = target.with_name(target.stem + ".layout.json")
    layout.write_text(view.layout(result.agents, result.peer_topics) + "\n", encoding="utf-8")
    return result, layout


def merge_folder(run_dir: str | Path) -> dict[str, Any]:
    """:func:`write_merged` into ``RUN_DIR/merged.mcap``, as a description (JSON-ready):
    ``file``, ``layout``, ``agents``, ``reference``, ``messages``, ``epoch_utc``,
    ``notes``; or, when the merge fails, ``error`` (what and why) and ``kept`` (the
    recordings, untouched). It never raises for a merge that fails: ``fedlab collect``
    reports it beside what it fetched."""
    directory = Path(run_dir)
    try:
        result, layout = write_merged(directory)
    except Exception as error:  # a merge that fails costs the merged file, never the run
        kept = sorted(p.name for p in directory.glob("*.mcap") if p.name != "merged.mcap")
        return {"error": f"{type(error).__name__}: {error}", "kept": kept}
    return {
        "file": str(directory / "merged.mcap"), "layout": str(layout), "agents": result.agents,
        "reference": result.reference, "messages": result.messages_out,
        "epoch_utc": result.metadata()["epoch_utc"], "notes": result.notes,
    }  # fmt: skip


def _is_merged(path: Path) -> bool:
    """Whether ``path`` is a merged file, by its header's library (``fedlab merge``): read
    from its start, not from its summary (a recording's chunk index is megabytes)."""
    try:
        with path.open("rb") as f:
            header = next(iter(StreamReader(f).records), None)
    except (McapError, OSError, ValueError):
        return False
    return isinstance(header, Header) and header.library == MERGE_LIBRARY


def _text(path: Path) -> str | None:
    """A run folder's JSON file's text (None: there is none), kept as it is."""
    return path.read_text(encoding="utf-8") if path.is_file() else None


def _write_file(
    paths: Sequence[Path], sink: IO[bytes], run_json: str | None, experiment_json: str | None
) -> MergeResult:
    writer = Writer(sink, chunk_size=OUTPUT_CHUNK)
    writer.start(profile="", library=MERGE_LIBRARY)
    result = merge(paths, writer, run_json, experiment_json)
    writer.finish()  # type: ignore[no-untyped-call]
    return result

"""The recording channels: one name per kind of message an agent records.

Every message is JSON; each carries ``t_exec`` (the agent's clock) and
``host_monotonic`` (the host's clock read at the same instant), so recordings
of agents on one machine line up exactly.

=====================  ============================================================
channel                message
=====================  ============================================================
``/pose/sent``         the pose published: t_exec, x, y, heading, vx, vy, omega
``/pose/received``     a pose received: agent, t (sender's clock), t_recv, pose
``/sync/exchange``     an accepted exchange: peer, t1, t2, t3, t2s, offset, delay,
                       estimate (the filtered offset after it)
``/reference``         guidance: t_sim, run_time, heading_ref, rate_ref, mode
``/truth``             a simulated platform's true pose (for evaluation)
``/control``           execution control: event, command, at, t_sim, mode
``/status``            the status message (as published)
=====================  ============================================================

Each channel's JSON schema types its fields (:data:`CHANNEL_TYPES`), so plots in
Foxglove find numbers without setup. Beside them, each recording carries two channels
in Foxglove's own types (protobuf, the Foxglove SDK's schemas), derived from
``/pose/sent`` and recorded with it, so a recording opened in Foxglove shows the
platform in its 3D panel:

=========  ============================  =====================================
``/tf``    ``foxglove.FrameTransforms``  ``fedlab_common`` -> ``LAB/NAME``
``/pose``  ``foxglove.PoseInFrame``      the pose in ``fedlab_common``
=========  ============================  =====================================

:class:`Channel` is a :class:`~enum.StrEnum`: a member *is* its name string, so
``messages[Channel.STATUS]`` and ``messages["/status"]`` find the same entry.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = [
    "CHANNEL_FIELDS",
    "CHANNEL_TYPES",
    "COMMON_FRAME",
    "FOXGLOVE_CHANNELS",
    "Channel",
    "json_schema",
    "recording_stem",
    "segment_stem",
]


class Channel(StrEnum):
    """A recording channel's name (the MCAP topic)."""

    POSE_SENT = "/pose/sent"
    POSE_RECEIVED = "/pose/received"
    SYNC_EXCHANGE = "/sync/exchange"
    REFERENCE = "/reference"
    TRUTH = "/truth"
    CONTROL = "/control"
    STATUS = "/status"


_POSE = ("x", "y", "heading", "vx", "vy", "omega")

CHANNEL_FIELDS: dict[Channel, tuple[str, ...]] = {
    Channel.POSE_SENT: ("t_exec", "host_monotonic", *_POSE),
    Channel.POSE_RECEIVED: ("agent", "t", "t_recv", "host_monotonic", *_POSE),
    Channel.SYNC_EXCHANGE: (
        "peer", "t1", "t2", "t3", "t2s", "offset", "delay", "estimate", "host_monotonic",
    ),
    Channel.REFERENCE: (
        "t_exec", "host_monotonic", "t_sim", "run_time", "heading_ref", "rate_ref", "mode",
        "valves_open",
    ),
    Channel.TRUTH: ("t_exec", "host_monotonic", *_POSE),
    Channel.CONTROL: (
        "event", "command", "at", "t_exec", "t_sim", "host_monotonic", "mode", "detail",
        "run_time",
    ),
    Channel.STATUS: ("agent", "t_exec", "host_monotonic", "peers", "counters"),
}  # fmt: skip
"""Each channel's message fields, in order (the MCAP JSON schema's properties)."""

_NUMBER, _MAYBE = "number", ["number", "null"]
_TYPES: dict[str, str | list[str]] = {
    "t_exec": _NUMBER, "host_monotonic": _NUMBER, "x": _NUMBER, "y": _NUMBER,
    "heading": _NUMBER, "vx": _NUMBER, "vy": _NUMBER, "omega": _NUMBER, "agent": "string",
    "t": _NUMBER, "t_recv": _NUMBER, "peer": "string", "t1": _NUMBER, "t2": _NUMBER,
    "t3": _NUMBER, "t2s": _MAYBE, "offset": _NUMBER, "delay": _NUMBER, "estimate": _MAYBE,
    "t_sim": _MAYBE, "run_time": _MAYBE, "heading_ref": _NUMBER, "rate_ref": _NUMBER,
    "mode": "string", "valves_open": "integer", "event": "string",
    "command": ["object", "null"], "at": _MAYBE, "detail": "string", "peers": "object",
    "counters": "object",
}  # fmt: skip

CHANNEL_TYPES: dict[Channel, dict[str, str | list[str]]] = {
    channel: {name: _TYPES[name] for name in fields} for channel, fields in CHANNEL_FIELDS.items()
}
"""Each channel's fields and their JSON types (``"number"``, ``["number", "null"]``...)."""

COMMON_FRAME = "fedlab_common"
"""The federation's common frame, as Foxglove and ROS 2 name it (every pose is in it)."""

FOXGLOVE_CHANNELS: dict[str, str] = {
    "/tf": "foxglove.FrameTransforms",
    "/pose": "foxglove.PoseInFrame",
}
"""The channels in Foxglove's types a recording carries beside :class:`Channel`'s, by
topic: their schema names."""


def json_schema(channel: Channel) -> dict[str, object]:
    """The JSON schema of a channel's messages: an object with typed properties (a message
    may carry more, as ``/status`` does)."""
    return {
        "title": f"fedlab {channel}",
        "type": "object",
        "properties": {name: {"type": kind} for name, kind in CHANNEL_TYPES[channel].items()},
    }


def segment_stem(agent: str, segment: int) -> str:
    """The stem of a run's ``segment``-th recording by ``agent`` (1: its first, from the
    start; 2, 3...: after each rejoin): ``rome-pinocchio``, ``rome-pinocchio.seg2``."""
    stem = recording_stem(agent)
    return stem if segment <= 1 else f"{stem}.seg{segment}"


def recording_stem(agent: str) -> str:
    """An agent's name as the stem of its recording's files: ``rome/pinocchio`` ->
    ``rome-pinocchio`` (``rome-pinocchio.mcap``, ``.jsonl``, ``.manifest.json``...)."""
    return agent.replace("/", "-")

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

:class:`Channel` is a :class:`~enum.StrEnum`: a member *is* its name string, so
``messages[Channel.STATUS]`` and ``messages["/status"]`` find the same entry.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["CHANNEL_FIELDS", "Channel"]


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
    ),
    Channel.STATUS: ("agent", "t_exec", "host_monotonic", "peers", "counters"),
}  # fmt: skip
"""Each channel's message fields, in order (the MCAP JSON schema's properties)."""

"""Reading what ``fedlab replay`` plays: one agent's recorded poses on their recorded
run time, and the platform it flew, from a per-agent recording (``LAB-NAME.mcap``:
channels ``/pose/sent``, ``/reference``, ``/status``, metadata ``fedlab.run``) or a
merged file (``fedlab merge``: the same channels under ``/LAB/NAME``, metadata
``LAB/NAME fedlab.run``).

A pose's run time comes from the agent's own ``/reference`` record of the same publish
(``run_time`` at ``t_exec`` of its control step, on the agent's estimate of the reference
clock): ``run_time + (t_exec_pose - t_exec_step)``. Poses sent outside a run (no run
time) are not played. The file is streamed, never loaded whole.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from federation.core.channels import Channel
from federation.core.replayplan import RecordedPose
from federation.core.wire import Pose
from federation.runtime.runs import METADATA as RUN_METADATA

__all__ = ["Recording", "hardware_of"]

_POSE_FIELDS = ("x", "y", "heading", "vx", "vy", "omega")


def hardware_of(platform: str | None) -> bool | None:
    """Whether the platform spec drives a real platform (None: unknown here)."""
    if not platform:
        return None
    from schemas.config import ConfigError
    from schemas.platform import platform_kind

    try:
        return bool(platform_kind(platform)[0].hardware)
    except (ConfigError, ValueError, ImportError):
        return None


class Recording:
    """One agent's part of an MCAP file (per-agent or merged)."""

    def __init__(self, path: Path, agent: str):
        self.path, self.agent = Path(path), agent
        with self.path.open("rb") as f:
            reader = make_reader(f)
            self.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
            summary = reader.get_summary()
            topics = {c.topic for c in summary.channels.values()} if summary else set()
        self.merged = any(t.startswith(f"/{agent}/") for t in topics)
        self.prefix = f"/{agent}" if self.merged else ""
        if not self.merged and self.recorded_agent() not in (None, agent):
            raise ValueError(f"{self.path}: a recording of {self.recorded_agent()}, not of {agent}")
        if f"{self.prefix}{Channel.POSE_SENT}" not in topics:
            raise ValueError(f"{self.path}: no poses sent by {agent} recorded")

    def _run_metadata(self, agent: str) -> dict[str, str]:
        key = f"{agent} {RUN_METADATA}" if self.merged else RUN_METADATA
        return self.metadata.get(key) or {}

    def recorded_agent(self) -> str | None:
        """The agent a per-agent recording is of (None: not said)."""
        agent = self._run_metadata(self.agent).get("agent")
        return agent or self._first_status(self.agent, "agent")

    def _first_status(self, agent: str, field: str) -> Any:
        """A field of the first recorded status of ``agent`` (None without one)."""
        prefix = f"/{agent}" if self.merged else ""
        with self.path.open("rb") as f:
            for _s, _c, message in make_reader(f).iter_messages(
                topics=[f"{prefix}{Channel.STATUS}"]
            ):
                return json.loads(message.data).get(field)
        return None

    def platform_of(self, agent: str) -> str | None:
        """The platform ``agent`` flew, as its config (or, without one, its status) says;
        None when the file does not say (another agent of a per-agent file)."""
        if not self.merged and agent != self.agent:
            return None
        config = self._run_metadata(agent).get("agent_config")
        if config:
            try:
                platform = json.loads(config).get("platform")
            except (ValueError, AttributeError):
                platform = None
            if isinstance(platform, str):
                return platform
        platform = self._first_status(agent, "platform")
        return platform if isinstance(platform, str) else None

    def knows(self, agent: str) -> bool:
        """Whether the file holds a recording of ``agent``."""
        return agent == self.agent or (self.merged and self.platform_of(agent) is not None)

    def poses(self) -> Iterator[RecordedPose]:
        """The recorded poses on their recorded run time, in order (streamed)."""
        sent, reference = (f"{self.prefix}{c}" for c in (Channel.POSE_SENT, Channel.REFERENCE))
        pending: list[dict[str, Any]] = []
        steps: list[dict[str, Any]] = []  # the last two control steps' references
        with self.path.open("rb") as f:
            for _s, channel, message in make_reader(f).iter_messages(
                topics=[sent, reference], log_time_order=True
            ):
                data = json.loads(message.data)
                if channel.topic == sent:
                    pending.append(data)
                    continue
                steps = [*steps[-1:], data]
                yield from _placed(pending, steps)
                pending = []
        yield from _placed(pending, steps)


def _placed(poses: list[dict[str, Any]], steps: list[dict[str, Any]]) -> Iterator[RecordedPose]:
    """``poses`` on run time, each by the latest control step at or before it."""
    for pose in poses:
        t = pose.get("t_exec")
        step = next(
            (s for s in reversed(steps) if isinstance(t, (int, float)) and s["t_exec"] <= t),
            None,
        )
        if step is None or step.get("run_time") is None or step.get("mode") != "running":
            continue
        yield RecordedPose(
            float(step["run_time"]) + (float(t) - float(step["t_exec"])),  # type: ignore[arg-type]
            Pose(*(float(pose[k]) for k in _POSE_FIELDS)),
        )

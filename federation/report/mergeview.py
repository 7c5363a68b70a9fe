"""What a merged run shows in Foxglove: messages in Foxglove's well-known types derived
from the recorded JSON, the plot channels' schemas, and the layout written beside it.

Every function takes decoded messages and the reference time they were mapped to (ns,
the merged file's log time) and returns messages; :mod:`federation.report.merge`
writes them. Topics are namespaced by agent (``/LAB/NAME/...``):

=============================  =========================  ===============================
topic                          schema                     from
=============================  =========================  ===============================
``/tf``                        foxglove.FrameTransforms   ``fedlab_common`` -> ``LAB/NAME``
                                                          (each pose sent) and
                                                          ``fedlab_common`` -> ``LAB`` (the
                                                          lab's table frame, from a status
                                                          that publishes one)
``/LAB/NAME/pose``             foxglove.PoseInFrame       each pose sent, common frame
``/scene``                     foxglove.SceneUpdate       each platform's footprint and
                                                          its lab's work area (statuses);
                                                          a docking run's corridor, in
                                                          the target's frame
``/LAB/NAME/log``              foxglove.Log               control events (commands, start,
                                                          end, ignored commands), holds
                                                          and their reasons, peers joining
                                                          and leaving
``/LAB/NAME/clock``            JSON (``CLOCK_SCHEMA``)    own clock, reference time, offset
                                                          estimate and its bound, the host
                                                          truth where known: at each point
                                                          of the estimate and each status
``/LAB/NAME/sync/PLAB/PNAME``  JSON (``PEER_SCHEMA``)     the agent's view of one peer (ms)
=============================  =========================  ===============================
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import foxglove.layouts as fl
from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    Log,
    LogLevel,
    Pose,
    PoseInFrame,
    SceneEntity,
    SceneUpdate,
    Vector3,
)
from pydantic import ValidationError

from federation.core.channels import COMMON_FRAME
from federation.runtime.scene import (
    area_corners,
    area_entity,
    footprint,
    platform_entity,
    rotation,
    stamp,
)
from schemas.messages import Workspace

__all__ = [
    "CLOCK_SCHEMA",
    "FOXGLOVE_TYPES",
    "PEER_SCHEMA",
    "WARNING_EVENTS",
    "clock_row",
    "control_log",
    "layout",
    "log",
    "peer_rows",
    "pose_messages",
    "schema_json",
    "status_view",
]

FOXGLOVE_TYPES: dict[str, Any] = {
    "foxglove.FrameTransforms": FrameTransforms,
    "foxglove.PoseInFrame": PoseInFrame,
    "foxglove.SceneUpdate": SceneUpdate,
    "foxglove.Log": Log,
}
"""The Foxglove types a merged file carries, by schema name (their schemas: the SDK's)."""

WARNING_EVENTS = frozenset({"aborted", "ignored", "recording_truncated"})
"""Control events logged as warnings; the others are information."""

_NUMBER = {"type": ["number", "null"]}
CLOCK_SCHEMA: dict[str, Any] = {
    "title": "fedlab merged clock",
    "type": "object",
    "properties": {
        "t_exec": _NUMBER | {"description": "the agent's own clock, s"},
        "t_ref": _NUMBER | {"description": "reference time it maps to, s"},
        "offset_s": _NUMBER | {"description": "reference minus own clock, as estimated, s"},
        "bound_s": _NUMBER | {"description": "error bound of t_ref, s"},
        "true_offset_s": _NUMBER | {"description": "reference minus own, host truth, s"},
        "error_s": _NUMBER | {"description": "offset_s minus true_offset_s, s"},
        "point": {
            "type": "boolean",
            "description": "a point of the estimate (linear between points); false: at a "
            "status line",
        },
    },
}
PEER_SCHEMA: dict[str, Any] = {
    "title": "fedlab merged peer view",
    "type": "object",
    "properties": {
        "offset_ms": _NUMBER | {"description": "peer clock minus the agent's, ms"},
        "delay_ms": _NUMBER | {"description": "median one-way delay, ms"},
        "error_bound_ms": _NUMBER | {"description": "worst-case offset error, ms"},
        "samples": {"type": ["integer", "null"]},
        "alive": {"type": ["boolean", "null"]},
    },
}


def _finite(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def pose_messages(
    agent: str, message: dict[str, Any], ns: int
) -> tuple[FrameTransforms, PoseInFrame] | None:
    """A pose sent as ``fedlab_common`` -> ``LAB/NAME`` and as a pose in the common frame,
    stamped ``ns`` (reference time); None for what is not a finite pose."""
    x, y, heading = (_finite(message.get(k)) for k in ("x", "y", "heading"))
    if x is None or y is None or heading is None:
        return None
    where, turn = Vector3(x=x, y=y, z=0.0), rotation(heading)
    tf = FrameTransform(
        timestamp=stamp(ns), parent_frame_id=COMMON_FRAME, child_frame_id=agent,
        translation=where, rotation=turn,
    )  # fmt: skip
    pose = PoseInFrame(
        timestamp=stamp(ns), frame_id=COMMON_FRAME, pose=Pose(position=where, orientation=turn)
    )
    return FrameTransforms(transforms=[tf]), pose


def log(agent: str, ns: int, text: str, warning: bool = False) -> Log:
    """One line of the agent's log, stamped ``ns``."""
    level = LogLevel.Warning if warning else LogLevel.Info
    return Log(timestamp=stamp(ns), level=level, message=text, name=agent)


def control_log(agent: str, message: dict[str, Any], ns: int) -> Log:
    """A ``/control`` event as a log line: the event, the command it carried (its name,
    issuer and start instant) and its detail."""
    event = str(message.get("event"))
    parts = [event]
    command = message.get("command")
    if isinstance(command, dict):
        parts.append(f"{command.get('command')} from {command.get('issuer')}")
        if command.get("at") is not None:
            parts.append(f"at reference {command['at']:.3f} s")
    if message.get("mode"):
        parts.append(f"mode {message['mode']}")
    if message.get("detail"):
        parts.append(str(message["detail"]))
    return log(agent, ns, ": ".join(parts[:1]) + (" " + ", ".join(parts[1:]) if parts[1:] else ""),
               event in WARNING_EVENTS)  # fmt: skip


def clock_row(
    t_exec: float, t_ref: float, bound: float | None, truth: float | None, point: bool = False
) -> dict[str, float | bool | None]:
    """A ``/LAB/NAME/clock`` message: own clock, reference time, the estimate, its bound,
    (where known) the truth and the estimate's error, and whether it is a point of the
    estimate (``point``) or at a status line."""
    offset = t_ref - t_exec
    return {
        "t_exec": t_exec,
        "t_ref": t_ref,
        "offset_s": offset,
        "bound_s": bound,
        "true_offset_s": truth,
        "error_s": None if truth is None else offset - truth,
        "point": point,
    }


def status_view(
    agent: str, status: dict[str, Any], before: dict[str, Any] | None, ns: int
) -> tuple[list[Log], list[SceneEntity], FrameTransforms | None]:
    """What a status line shows: log lines for a hold set, changed or lifted and for
    peers that joined or left since ``before`` (the agent's previous status); the
    platform's footprint and its lab's work area; the lab's table frame in the common
    frame (``fedlab_common`` -> ``LAB``) when the status publishes a work area."""
    before = before or {}
    lines = []
    hold, held = status.get("hold"), before.get("hold")
    if hold != held:
        text = f"hold: {hold}" if hold else f"hold lifted (was: {held})"
        lines.append(log(agent, ns, text, warning=bool(hold)))
    peers, known = _peers(status), _peers(before)
    for peer in sorted(set(peers) | set(known)):
        now = peer in peers and (peers[peer] or {}).get("alive", True)
        was = peer in known and (known[peer] or {}).get("alive", True)
        if now != was:
            lines.append(log(agent, ns, f"peer {peer} {'joined' if now else 'left'}", not now))
    entities = [platform_entity(agent, footprint(str(status.get("platform") or "")), ns)]
    frame = None
    try:
        workspace = Workspace.model_validate(status["workspace"])
    except (KeyError, ValidationError):
        workspace = None
    if workspace is not None:
        entities.append(area_entity(agent, area_corners(workspace), ns))
        lab = agent.split("/")[0]
        origin = workspace.frame.origin
        frame = FrameTransforms(
            transforms=[
                FrameTransform(
                    timestamp=stamp(ns),
                    parent_frame_id=COMMON_FRAME,
                    child_frame_id=lab,
                    translation=Vector3(x=origin[0], y=origin[1], z=0.0),
                    rotation=rotation(math.radians(workspace.frame.rotation_deg)),
                )
            ]
        )
    return lines, entities, frame


def _peers(status: dict[str, Any]) -> dict[str, Any]:
    peers = status.get("peers")
    return peers if isinstance(peers, dict) else {}


def peer_rows(status: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(peer, its ``/LAB/NAME/sync/PLAB/PNAME`` message) for each peer of a status."""
    rows = []
    for peer, view in sorted(_peers(status).items()):
        view = view if isinstance(view, dict) else {}

        def ms(key: str, view: dict[str, Any] = view) -> float | None:
            value = _finite(view.get(key))
            return None if value is None else value * 1e3

        rows.append((str(peer), {
            "offset_ms": ms("offset"), "delay_ms": ms("delay"),
            "error_bound_ms": ms("error_bound"), "samples": view.get("samples"),
            "alive": view.get("alive"),
        }))  # fmt: skip
    return rows


def _plot(title: str, paths: Sequence[tuple[str, str]]) -> fl.PlotPanel:
    series = [fl.PlotSeries(value=value, label=label) for value, label in paths]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True))


def _series(agents: Sequence[str], field: str) -> list[tuple[str, str]]:
    return [(f"/{a}/clock.{field}", a) for a in agents]


def layout(agents: Sequence[str], peer_topics: Sequence[str] = ()) -> str:
    """The Foxglove layout of a merged run (JSON): 3D in ``fedlab_common`` (platforms,
    work areas), every agent's log, headings (sent and guidance reference) and clock
    estimates with their bounds, and each peer view's offset and delay."""
    three_d = fl.ThreeDeePanel(
        title="Platforms and work areas in the common frame (reference time)",
        config=fl.ThreeDeeConfig(
            fixed_frame=COMMON_FRAME,
            follow_tf=COMMON_FRAME,
            topics={"/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
        ),
    )
    headings = [(f"/{a}/pose/sent.heading", f"{a} sent") for a in agents]
    headings += [(f"/{a}/reference.heading_ref", f"{a} reference") for a in agents]
    panels: list[fl.Content] = [
        fl.LogPanel(title="Events, holds and joins", config=fl.LogConfig(show_name=True)),
        _plot("Heading (rad)", headings),
        _plot(
            "Offset estimate, reference minus own (s)",
            [(f"/{a}/clock.offset_s", a) for a in agents],
        ),
        _plot("Stamp error bound (s)", [(f"/{a}/clock.bound_s", a) for a in agents]),
        _plot("Offset estimate minus host truth (s)", [(f"/{a}/clock.error_s", a) for a in agents]),
    ]
    if peer_topics:
        panels.append(_plot("One-way delay (ms)", [(f"{t}.delay_ms", t) for t in peer_topics]))
    right = fl.SplitContainer(
        direction="column", items=[fl.SplitItem(proportion=1, content=p) for p in panels]
    )
    content = fl.SplitContainer(
        direction="row",
        items=[
            fl.SplitItem(proportion=3, content=three_d),
            fl.SplitItem(proportion=2, content=right),
        ],
    )
    return fl.Layout(content=content).to_json()


def schema_json(schema: dict[str, Any]) -> bytes:
    """A JSON schema as a schema record's data."""
    return json.dumps(schema).encode()

"""A live view of a federation in Foxglove (``fedlab foxglove``), on the Foxglove SDK's
WebSocket server (protocol ``foxglove.websocket.v1``).

It subscribes as ``fedlab monitor`` does (every agent's status, and liveliness with
history) and to every agent's pose, and logs on these channels:

===================================  =========================  ==========================
topic                                schema                     what
===================================  =========================  ==========================
``/tf``                              foxglove.FrameTransforms   ``fedlab_common`` ->
                                                                ``LAB/NAME``, every pose
``/scene``                           foxglove.SceneUpdate       each platform's footprint
                                                                and name (frame-locked to
                                                                its frame), and each work
                                                                area's outline (common
                                                                frame), once a second
``/fedlab/peers``                    JSON (``PEERS_SCHEMA``)    one row per agent and peer:
                                                                offset, delay, error bound
``/fedlab/sync/LAB/NAME/PLAB/PNAME`` JSON (``SYNC_SCHEMA``)     LAB/NAME's view of one peer,
                                                                for plots (ms)
``/fedlab/run``                      JSON (``RUN_SCHEMA``)      one row per agent: role,
                                                                mode, run time, hold
===================================  =========================  ==========================

Times: each message is stamped with this host's wall clock when it arrived (a live
view; recordings carry the agents' own clocks). The footprint is a square of side
``2 * moment_arm`` (the thrusters' lines of action) of the platform's preset, or
``DEFAULT_FOOTPRINT`` m when the status names no preset (kinematic, a ROS 2 platform).
An agent that keeps its platform inside an area (formation, docking) publishes its
lab's frame and that area in its status (``workspace``): the area's corners,
:math:`p_c = R(\\theta) p_t + o`, are drawn as a closed line in ``fedlab_common``
(:func:`area_corners`), labelled ``LAB work area``. A status that does not validate, or
names another agent than its key, is counted in ``malformed`` and dropped, as in the
monitor.

The parts that decide what is shown take data and return rows
(:func:`peer_rows`, :func:`run_row`, :func:`footprint`, :func:`area_corners`,
:func:`scene`, :func:`layout`); :class:`LiveView` moves them from Zenoh to the SDK.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import foxglove
import foxglove.layouts as fl
import zenoh
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    Vector3,
)
from pydantic import ValidationError

from federation.core import keys, wire
from federation.core.keys import AgentId
from federation.runtime.scene import DEFAULT_FOOTPRINT, area_corners, footprint
from federation.runtime.scene import area_entity as _area_entity
from federation.runtime.scene import platform_entity as _entity
from federation.runtime.scene import rotation as _rotation
from federation.runtime.scene import stamp as _stamp
from federation.runtime.session import undeclare_all
from schemas.messages import Status

__all__ = [
    "COMMON_FRAME",
    "DEFAULT_FOOTPRINT",
    "PEERS_SCHEMA",
    "RUN_SCHEMA",
    "SYNC_SCHEMA",
    "LiveView",
    "area_corners",
    "footprint",
    "layout",
    "layout_topics",
    "peer_rows",
    "run_row",
    "scene",
    "sync_topic",
]

log = logging.getLogger("fedlab.foxglove")

COMMON_FRAME = "fedlab_common"
SCENE_PERIOD = 1.0  # s between scene updates (a client that joins late gets one soon)
MAX_STATUS_BYTES = 1 << 20

_NUMBER = {"type": ["number", "null"]}
SYNC_SCHEMA: dict[str, Any] = {
    "type": "object",
    "properties": {
        "offset_ms": _NUMBER | {"description": "peer clock minus the agent's, ms"},
        "delay_ms": _NUMBER | {"description": "median one-way delay, ms"},
        "error_bound_ms": _NUMBER | {"description": "worst-case offset error, ms"},
        "samples": {"type": "integer"},
        "alive": {"type": "boolean"},
    },
}


def _rows_schema(**columns: Any) -> dict[str, Any]:
    """The JSON schema of a table: ``{"rows": [{column: value, ...}, ...]}``."""
    row = {"type": "object", "properties": columns}
    return {"type": "object", "properties": {"rows": {"type": "array", "items": row}}}


PEERS_SCHEMA = _rows_schema(
    agent={"type": "string"}, peer={"type": "string"}, **SYNC_SCHEMA["properties"]
)
RUN_SCHEMA = _rows_schema(
    agent={"type": "string"},
    role={"type": "string"},
    mode={"type": "string"},
    run_time=_NUMBER | {"description": "s since the start"},
    t_sim=_NUMBER | {"description": "reference time, s"},
    hold={"type": ["string", "null"]},
    alive={"type": "boolean"},
)


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else value


def _ms(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else value * 1e3


def peer_rows(status: Status) -> list[dict[str, Any]]:
    """One row per peer of ``status``: offset, delay and error bound (ms), samples, alive."""
    return [
        {
            "agent": status.agent,
            "peer": peer,
            "offset_ms": _ms(view.offset),
            "delay_ms": _ms(view.delay),
            "error_bound_ms": _ms(view.error_bound),
            "samples": view.samples,
            "alive": view.alive,
        }
        for peer, view in sorted(status.peers.items())
    ]


def run_row(status: Status, alive: bool = True) -> dict[str, Any]:
    """An agent's run: role, mode, run time, reference time, hold."""
    return {
        "agent": status.agent,
        "role": status.role,
        "mode": status.mode,
        "run_time": _finite(status.run_time),  # a NaN is not JSON: the table unreadable
        "t_sim": _finite(status.t_sim),
        "hold": status.hold,
        "alive": alive,
    }


MAX_SYNC_CHANNELS = 1024
"""Sync plot channels at most (one per agent and peer): statuses listing thousands of
made-up peers would make a channel each, 15 MiB a status."""


def _is_agent(name: str) -> bool:
    try:
        keys.AgentId.parse(name)
    except ValueError:
        return False
    return True


def sync_topic(agent: str, peer: str) -> str:
    """The plot topic of ``agent``'s view of ``peer``: ``/fedlab/sync/LAB/NAME/PLAB/PNAME``."""
    return f"/fedlab/sync/{agent}/{peer}"


def _plot(title: str, field: str, sync_topics: Sequence[str]) -> fl.PlotPanel:
    def label(topic: str) -> str:  # /fedlab/sync/L/N/PL/PN: L/N -> PL/PN
        parts = topic.removeprefix("/fedlab/sync/").split("/")
        return "/".join(parts[:2]) + " -> " + "/".join(parts[2:])

    series = [fl.PlotSeries(value=f"{t}.{field}", label=label(t)) for t in sync_topics]
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True))


def layout(sync_topics: Sequence[str] = ()) -> fl.Layout:
    """The Foxglove layout of this view: 3D in ``fedlab_common`` (transforms, footprints,
    work areas), the run and per-peer tables and, for the given plot topics
    (:func:`sync_topic`), plots of offset, delay and error bound, one series per topic.
    With no topics, the panels every federation has (``deploy/foxglove/fedlab.json``)."""
    three_d = fl.ThreeDeePanel(
        title="Platforms and work areas in the common frame",
        config=fl.ThreeDeeConfig(
            fixed_frame=COMMON_FRAME,
            follow_tf=COMMON_FRAME,
            topics={"/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
        ),
    )
    panels: list[fl.Content] = [
        fl.TablePanel(title="Run", config=fl.TableConfig(topic_path="/fedlab/run.rows")),
        fl.TablePanel(
            title="Sync per peer", config=fl.TableConfig(topic_path="/fedlab/peers.rows")
        ),
    ]
    if sync_topics:
        panels += [
            _plot("Offset, peer minus agent (ms)", "offset_ms", sync_topics),
            _plot("One-way delay (ms)", "delay_ms", sync_topics),
            _plot("Offset error bound (ms)", "error_bound_ms", sync_topics),
        ]
    right = fl.SplitContainer(
        direction="column", items=[fl.SplitItem(proportion=1, content=p) for p in panels]
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=three_d),
                fl.SplitItem(proportion=2, content=right),
            ],
        )
    )


def layout_topics(layout_json: Any) -> set[str]:
    """Every topic a layout (parsed JSON) reads: tables' ``topicPath``, plot series'
    ``value`` (the topic before the first ``.``), and the 3D panel's ``topics``."""
    found: set[str] = set()
    stack = [layout_json]
    while stack:
        node = stack.pop()
        if isinstance(node, list):
            stack.extend(node)
        elif isinstance(node, dict):
            for key, value in node.items():
                if key in ("topicPath", "value") and isinstance(value, str):
                    found.add(value.split(".")[0])
                elif key == "topics" and isinstance(value, dict):
                    found.update(value)
                else:
                    stack.append(value)
    return found


def write_layout(path: Path, sync_topics: Sequence[str]) -> None:
    """Write :func:`layout` to ``path`` whole (a reader never sees half a file)."""
    partial = path.with_name(path.name + ".partial")
    partial.write_text(layout(sync_topics).to_json() + "\n", encoding="utf-8")
    os.replace(partial, path)


def frame_transform(agent: AgentId, pose: wire.Pose, ns: int) -> FrameTransform:
    """``fedlab_common`` -> ``LAB/NAME`` at wall-clock ``ns``."""
    return FrameTransform(
        timestamp=_stamp(ns),
        parent_frame_id=COMMON_FRAME,
        child_frame_id=str(agent),
        translation=Vector3(x=pose.x, y=pose.y, z=0.0),
        rotation=_rotation(pose.heading),
    )


def scene(
    present: Sequence[tuple[str, Status]], gone: Sequence[str], drawn: set[str], ns: int
) -> tuple[SceneUpdate, set[str]]:
    """The scene at wall-clock ``ns``: the footprint of every agent ``present`` (LAB/NAME
    and its last status) and the work area of those that publish one; deletions of the
    footprints of the agents ``gone`` and of the areas ``drawn`` before but no longer
    published. Returns the update and the agents whose area is now drawn."""
    entities = [_entity(agent, footprint(status.platform), ns) for agent, status in present]
    areas = {a: s.workspace for a, s in present if s.workspace is not None}
    entities += [_area_entity(a, area_corners(w), ns) for a, w in areas.items()]
    ids = [f"platform:{a}" for a in gone] + [f"area:{a}" for a in sorted(drawn - set(areas))]
    deletions = [
        SceneEntityDeletion(timestamp=_stamp(ns), type=SceneEntityDeletionType.MatchingId, id=i)
        for i in ids
    ]
    return SceneUpdate(deletions=deletions, entities=entities), set(areas)


class LiveView:
    """Every agent of ``federation`` on ``session``, logged to ``context``'s channels.
    ``start()``, ``step()`` about every 0.1 s, ``close()`` before the session closes."""

    def __init__(
        self,
        session: zenoh.Session,
        context: foxglove.Context,
        federation: str = keys.DEFAULT_FEDERATION,
        wall_ns: Callable[[], int] = time.time_ns,
    ):
        self.session = session
        self.context = context
        self.federation = keys.validate_name(federation, "federation name")
        self.wall_ns = wall_ns
        self.malformed = 0
        self.poses = 0
        self._lock = threading.Lock()
        self._status: dict[AgentId, Status] = {}
        self._alive: dict[AgentId, bool] = {}
        self._gone: list[str] = []  # agents whose footprint is to be deleted
        self._areas_drawn: set[str] = set()  # agents whose work area is on the scene
        self._sync: dict[str, foxglove.Channel] = {}  # grows under the lock
        self._declared: list[Any] = []
        self._next_scene = 0
        self.tf = FrameTransformsChannel("/tf", context=context)
        self.scene = SceneUpdateChannel("/scene", context=context)
        self.peers = foxglove.Channel("/fedlab/peers", schema=PEERS_SCHEMA, context=context)
        self.run = foxglove.Channel("/fedlab/run", schema=RUN_SCHEMA, context=context)

    def start(self) -> None:
        callback = zenoh.handlers.Callback
        fed, s = self.federation, self.session
        try:
            self._declared.append(
                s.declare_subscriber(
                    keys.all_of(fed, "pose"), callback(self._on_pose, indirect=False)
                )
            )
            self._declared.append(
                s.declare_subscriber(
                    keys.all_of(fed, "status"), callback(self._on_status, indirect=False)
                )
            )
            self._declared.append(
                s.liveliness().declare_subscriber(
                    keys.all_agents(fed),
                    callback(self._on_liveliness, indirect=False),
                    history=True,
                )
            )
        except Exception:
            self.close()
            raise

    def close(self) -> None:
        undeclare_all(self._declared)

    # -- Zenoh callbacks: quick, never raise ---------------------------------------------
    def _on_pose(self, sample: zenoh.Sample) -> None:
        ns = self.wall_ns()
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            try:
                decoded = wire.decode_pose(sample.payload.to_bytes())
            except wire.DecodeError:
                with self._lock:
                    self.malformed += 1
                return
            if parsed is None:
                return
            transforms = FrameTransforms(transforms=[frame_transform(parsed[0], decoded.pose, ns)])
            self.tf.log(transforms, log_time=ns)
            with self._lock:
                self.poses += 1
        except Exception:
            log.exception("pose sample on %s failed", sample.key_expr)

    def _on_status(self, sample: zenoh.Sample) -> None:
        ns = self.wall_ns()
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            payload = sample.payload.to_bytes()
            status = None
            if parsed is not None and parsed[1] == "status" and len(payload) <= MAX_STATUS_BYTES:
                try:
                    status = Status.model_validate_json(payload)
                except ValidationError:
                    status = None
            if status is None or parsed is None or status.agent != str(parsed[0]):
                with self._lock:
                    self.malformed += 1
                return
            with self._lock:
                self._status[parsed[0]] = status
                self._alive.setdefault(parsed[0], True)
            for row in peer_rows(status):
                topic = sync_topic(row["agent"], row["peer"])
                channel = self._sync.get(topic)
                if channel is None:
                    if not _is_agent(row["peer"]) or len(self._sync) >= MAX_SYNC_CHANNELS:
                        with self._lock:  # a forged status's peers, or too many of them
                            self.malformed += 1
                        continue
                    with self._lock:
                        channel = self._sync[topic] = foxglove.Channel(
                            topic, schema=SYNC_SCHEMA, context=self.context
                        )
                channel.log({k: v for k, v in row.items() if k not in ("agent", "peer")},
                            log_time=ns)  # fmt: skip
            self._log_tables(ns)
        except Exception:
            log.exception("status sample on %s failed", sample.key_expr)

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        try:
            parsed = keys.parse_agent_key(self.federation, str(sample.key_expr))
            if parsed is None or parsed[1] is not None:
                return
            alive = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                self._alive[parsed[0]] = alive
                if not alive:
                    self._gone.append(str(parsed[0]))
        except Exception:
            log.exception("liveliness sample on %s failed", sample.key_expr)

    def sync_topics(self) -> list[str]:
        """The per-peer plot topics advertised so far, sorted."""
        with self._lock:
            return sorted(self._sync)

    # -- logging -----------------------------------------------------------------------
    def _log_tables(self, ns: int) -> None:
        with self._lock:
            known = sorted(self._status.items())
            alive = dict(self._alive)
        rows = [r for _, status in known for r in peer_rows(status)]
        self.peers.log({"rows": rows}, log_time=ns)
        runs = [run_row(status, alive.get(agent, True)) for agent, status in known]
        self.run.log({"rows": runs}, log_time=ns)

    def step(self) -> None:
        """Log the scene if it is due: footprints and work areas of the agents present,
        deletions of those that left (and of areas no longer published)."""
        ns = self.wall_ns()
        if ns < self._next_scene:
            return
        self._next_scene = ns + int(SCENE_PERIOD * 1e9)
        with self._lock:
            present = [(str(a), s) for a, s in sorted(self._status.items()) if self._alive.get(a)]
            gone, self._gone = self._gone, []
        try:
            update, self._areas_drawn = scene(present, gone, self._areas_drawn, ns)
            self.scene.log(update, log_time=ns)
        except Exception:  # one agent's odd status must not stop the view
            log.exception("scene not drawn")


def serve(
    session: zenoh.Session,
    stop: threading.Event,
    federation: str = keys.DEFAULT_FEDERATION,
    host: str = "127.0.0.1",
    port: int = 8765,
    duration: float | None = None,
    layout_file: Path | None = None,
) -> None:
    """Serve the live view on ``host:port`` until ``stop`` (or ``duration`` seconds);
    with ``layout_file``, keep a layout of the agents seen there (rewritten when a new
    agent or peer appears). Raises OSError if ``layout_file`` cannot be written."""
    topics: list[str] = []
    if layout_file is not None:
        write_layout(layout_file, topics)  # before serving: a bad path fails at once
    context = foxglove.Context()
    server = foxglove.start_server(name="fedlab", host=host, port=port, context=context)
    view = LiveView(session, context, federation)
    try:
        view.start()
        log.info(
            "Foxglove live view of federation %s on ws://%s:%d (open it in Foxglove: "
            "Open connection, Foxglove WebSocket)", federation, host, server.port,
        )  # fmt: skip
        deadline = math.inf if duration is None else time.monotonic() + duration
        while not stop.is_set() and time.monotonic() < deadline:
            view.step()
            if layout_file is not None and (seen := view.sync_topics()) != topics:
                topics = seen
                write_layout(layout_file, topics)
                log.info("layout for %d peer views written to %s", len(topics), layout_file)
            stop.wait(0.1)
    finally:
        view.close()
        server.stop()

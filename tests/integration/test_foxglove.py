"""``fedlab foxglove``: a WebSocket client speaking Foxglove's protocol sees the federation.

Real processes on loopback (two routers, a leader, a follower and ``fedlab foxglove``
through the ``labs`` fixture); the client is the ``websockets`` library speaking
Foxglove's WebSocket protocol as Foxglove does: it reads the server's channel advertisement,
subscribes, and decodes the binary message frames (opcode 1, subscription id, time,
payload) with the schema the server advertised (protobuf for Foxglove's types, via
the ``protobuf`` library; JSON for fedlab's tables). It sees the leader's transform and
the follower's sync row; with the docking experiment, each lab's work area on ``/scene``
in the common frame (checked against the experiment and platform files) and a layout
(``--layout``) that reads only topics the server advertises.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import time
from pathlib import Path
from typing import Any

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from loopback import FOLLOWER, LEADER, Agent, Labs, PoseTap
from websockets.sync.client import ClientConnection, connect

from federation.fleet.launch import free_port, wait_for
from federation.runtime.foxglove import layout_topics
from schemas.experiment import load_experiment
from schemas.platform import load_platform
from schemas.scenario import LabFrame

# Foxglove's WebSocket protocol; SDK 0.30's server names it foxglove.sdk.v1 (the protocol
# of foxglove.websocket.v1, renamed) and refuses a client offering only the old name.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def protobuf_class(channel: dict[str, Any]) -> Any:
    """The message class of an advertised protobuf channel, from its FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


class FoxgloveClient:
    """A client of ``foxglove.websocket.v1``: channels by topic, subscribe, read frames."""

    def __init__(self, ws: ClientConnection):
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.subscriptions: dict[int, dict[str, Any]] = {}

    def read(self, timeout: float) -> tuple[dict[str, Any], bytes] | None:
        """The next message frame (its channel and payload) within ``timeout`` s; text
        frames (advertisements) are taken in on the way."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                return None
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    self.channels.update({c["topic"]: c for c in op["channels"]})
                continue
            if frame[0] == 0x01:  # messageData: subscription id, log time (ns), payload
                sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                return self.subscriptions[sub_id], frame[13:]
        return None

    def wait_channel(self, topic: str, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while topic not in self.channels and time.monotonic() < deadline:
            self.read(0.1)
        assert topic in self.channels, sorted(self.channels)
        return self.channels[topic]

    def subscribe(self, channel: dict[str, Any]) -> None:
        sub_id = len(self.subscriptions) + 1
        self.subscriptions[sub_id] = channel
        subscription = {"id": sub_id, "channelId": channel["id"]}
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [subscription]}))


def open_client(port: int, timeout: float) -> ClientConnection:
    """Connect to the server once it listens (bounded)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return connect(
                f"ws://127.0.0.1:{port}",
                subprotocols=SUBPROTOCOLS,  # type: ignore[arg-type]
                open_timeout=2,
            )
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


@pytest.mark.integration
def test_a_foxglove_client_sees_the_leaders_transform_and_the_sync(labs: Labs) -> None:
    pair = labs.pair()
    leader = labs.leader(pair.kiruna, "--platform", "knatte")  # a noisy, moving pose
    follower = labs.follower(pair.rome)
    port = free_port()
    view = Agent(
        labs.fleet, "foxglove",
        ["foxglove", "--port", str(port), "-e", pair.rome.endpoint], who="foxglove",
    )  # fmt: skip
    view.start()
    # A start-up wait, not a latency: with other suites on the 2 cores, five processes
    # starting at once were seen to take 10 s to come up (routers included).
    leader.wait_status(timeout=30)
    tap = PoseTap(pair.kiruna.endpoint, f"fedlab/default/{LEADER}/pose")
    try:
        # The tap's subscription reaches the router before the view's, so each pose the
        # view can show is one the tap saw (it may arrive a moment after the view's).
        assert wait_for(lambda: len(tap.received()) >= 3, timeout=10), "tap got no poses"
        with open_client(port, timeout=15) as ws:
            check_view(ws, tap, follower)
    finally:
        tap.close()
    assert view.alive()


def check_view(ws: ClientConnection, tap: PoseTap, follower: Agent) -> None:
    """The leader's transform within 1 s of subscribing, and the follower's sync row."""
    assert ws.subprotocol in SUBPROTOCOLS
    client = FoxgloveClient(ws)
    tf = client.wait_channel("/tf", timeout=5)
    assert tf["schemaName"] == "foxglove.FrameTransforms"
    decode = protobuf_class(tf)
    client.subscribe(tf)
    subscribed = time.monotonic()
    transform = None
    while transform is None and time.monotonic() - subscribed < 1.0:
        frame = client.read(1.0 - (time.monotonic() - subscribed))
        if frame is None or frame[0]["topic"] != "/tf":
            continue
        message = decode.FromString(frame[1])
        found = [t for t in message.transforms if t.child_frame_id == LEADER]
        transform = found[0] if found else None
    assert transform is not None, "no transform of the leader within 1 s"
    within = time.monotonic() - subscribed
    assert transform.parent_frame_id == "fedlab_common"
    tr = transform.translation

    def published() -> list[Any]:
        return [
            s.pose
            for s in tap.received()
            if abs(s.pose.x - tr.x) <= 1e-9 and abs(s.pose.y - tr.y) <= 1e-9
        ]

    assert wait_for(lambda: bool(published()), timeout=2), (tr, tap.received()[-3:])
    heading = yaw(transform.rotation)
    assert any(abs(math.remainder(p.heading - heading, math.tau)) < 1e-9 for p in published())
    print(f"leader's transform {within * 1e3:.0f} ms after subscribing ({ws.subprotocol})")

    # Offset, delay and error bound per peer: the follower's view of the leader.
    follower.wait_samples(LEADER, 10, timeout=15)
    peers = client.wait_channel("/fedlab/peers", timeout=5)
    assert peers["encoding"] == "json"
    client.subscribe(peers)
    rows: list[dict[str, Any]] = []

    def follower_row() -> bool:
        frame = client.read(0.5)
        if frame is not None and frame[0]["topic"] == "/fedlab/peers":
            rows[:] = json.loads(frame[1])["rows"]
        return any(
            r["agent"] == FOLLOWER and r["peer"] == LEADER and r["offset_ms"] is not None
            for r in rows
        )

    assert wait_for(follower_row, timeout=5, interval=0), rows
    row = next(r for r in rows if r["agent"] == FOLLOWER and r["peer"] == LEADER)
    line = follower.latest()["peers"][LEADER]
    assert row["delay_ms"] > 0 and row["error_bound_ms"] >= 0
    assert row["offset_ms"] == pytest.approx(line["offset"] * 1e3, abs=5.0)
    assert "/fedlab/run" in client.channels and "/scene" in client.channels
    assert client.channels["/scene"]["schemaName"] == "foxglove.SceneUpdate"


DOCKING = Path(__file__).resolve().parents[2] / "deploy" / "experiments" / "docking.toml"


def expected_corners(lab: str, platform: str) -> list[tuple[float, float]]:
    """A lab's work area in the common frame, from the experiment and platform files:
    (x, y) of the table frame rotated by the lab's rotation, then moved to its origin."""
    frame = load_experiment(DOCKING).frames.get(lab, LabFrame())
    x_min, x_max, y_min, y_max = load_platform(platform).usable_area
    c, s = math.cos(math.radians(frame.rotation_deg)), math.sin(math.radians(frame.rotation_deg))
    ox, oy = frame.origin
    table = [(x_min, y_min), (x_max, y_min), (x_max, y_max), (x_min, y_max)]
    return [(c * x - s * y + ox, s * x + c * y + oy) for x, y in table]


@pytest.mark.integration
def test_each_labs_work_area_is_drawn_and_the_layout_reads_advertised_topics(
    labs: Labs,
) -> None:
    """The docking experiment (Rome's table turned 180 deg, 1.3 m away): both agents keep
    their platforms in an area; the view draws each area in the common frame, and the
    layout it writes reads only topics it advertises, a per-peer plot among them."""
    pair = labs.pair()
    experiment = ["--experiment", str(DOCKING), "--runs-dir", str(labs.tmp / "runs")]
    leader = labs.agent(LEADER, pair.kiruna, *experiment)
    follower = labs.agent(FOLLOWER, pair.rome, *experiment)
    port, layout_file = free_port(), labs.tmp / "layout.json"
    view = Agent(
        labs.fleet, "foxglove",
        ["foxglove", "--port", str(port), "--layout", str(layout_file), "-e", pair.rome.endpoint],
        who="foxglove",
    )  # fmt: skip
    view.start()
    for agent in (leader, follower):  # each publishes its lab's frame and area
        agent.until(lambda line: line.get("workspace") is not None, 30, "a workspace")
    with open_client(port, timeout=15) as ws:
        client = FoxgloveClient(ws)
        scene = client.wait_channel("/scene", timeout=5)
        assert scene["schemaName"] == "foxglove.SceneUpdate"
        decode = protobuf_class(scene)
        client.subscribe(scene)
        areas: dict[str, Any] = {}

        def both_areas() -> bool:
            frame = client.read(0.5)
            if frame is not None and frame[0]["topic"] == "/scene":
                update = decode.FromString(frame[1])
                areas.update({e.id: e for e in update.entities if e.id.startswith("area:")})
            return {f"area:{LEADER}", f"area:{FOLLOWER}"} <= set(areas)

        assert wait_for(both_areas, timeout=10, interval=0), sorted(areas)
        for agent, platform in ((LEADER, "knatte"), (FOLLOWER, "pinocchio")):
            entity = areas[f"area:{agent}"]
            assert entity.frame_id == "fedlab_common"
            (line,) = entity.lines
            got = [(p.x, p.y) for p in line.points]
            expected = expected_corners(agent.split("/")[0], platform)
            assert got == [pytest.approx(e, abs=1e-9) for e in expected], (agent, got, expected)
        print("work areas (common frame):", {a: [(p.x, p.y) for p in e.lines[0].points]
                                             for a, e in areas.items()})  # fmt: skip

        # The layout names the follower's view of the leader once the view has seen it.
        sync = f"/fedlab/sync/{FOLLOWER}/{LEADER}"
        topics: set[str] = set()

        def layout_has_plot() -> bool:
            client.read(0.2)  # take in advertisements meanwhile
            if layout_file.exists():
                topics.clear()
                topics.update(layout_topics(json.loads(layout_file.read_text())))
            return sync in topics

        assert wait_for(layout_has_plot, timeout=15, interval=0), sorted(topics)
        client.wait_channel(sync, timeout=5)
        assert topics <= set(client.channels), sorted(topics - set(client.channels))
        assert {"/scene", "/fedlab/run", "/fedlab/peers"} <= topics
    assert view.alive()

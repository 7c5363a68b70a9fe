"""Draw what a Foxglove client receives from a running ``fedlab foxglove``, with matplotlib:
a substitute for a screenshot where Foxglove itself cannot run (README's picture).

    fedlab foxglove --port 8765 -e tcp/127.0.0.1:7447 &
    .venv/bin/python deploy/foxglove/draw_view.py --url ws://127.0.0.1:8765 \\
        --out deploy/foxglove/view-substitute.png

It connects as Foxglove does (``foxglove.sdk.v1``), subscribes to ``/tf``, ``/scene``,
``/fedlab/run`` and ``/fedlab/peers`` for ``--seconds``, decodes each message with the
schema the server advertised, and draws the last of each: the work areas (common frame),
every platform's footprint and nose placed by its transform, and the two tables.
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import struct
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import connect

TOPICS = ("/tf", "/scene", "/fedlab/run", "/fedlab/peers")


def _decoder(channel: dict[str, Any]) -> Any:
    if channel["encoding"] == "json":
        return lambda data: json.loads(data)
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))
    return cls.FromString


def collect(url: str, seconds: float) -> dict[str, Any]:
    """The transforms (by child frame), scene entities (by id) and tables received."""
    transforms: dict[str, Any] = {}
    entities: dict[str, Any] = {}
    tables: dict[str, Any] = {}
    subs: dict[int, tuple[str, Any]] = {}
    with connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5) as ws:  # type: ignore[list-item]
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                frame = ws.recv(timeout=left)
            except TimeoutError:
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") != "advertise":
                    continue
                wanted = [c for c in op["channels"] if c["topic"] in TOPICS]
                for c in wanted:
                    subs[c["id"]] = (c["topic"], _decoder(c))
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": c["id"], "channelId": c["id"]} for c in wanted]}))  # fmt: skip
                continue
            if frame[0] != 0x01:
                continue
            (sub_id,) = struct.unpack_from("<I", frame, 1)
            topic, decode = subs[sub_id]
            message = decode(frame[13:])
            if topic == "/tf":
                transforms.update({t.child_frame_id: t for t in message.transforms})
            elif topic == "/scene":
                entities.update({e.id: e for e in message.entities})
                for d in message.deletions:
                    entities.pop(d.id, None)
            else:
                tables[topic] = message["rows"]
    return {"transforms": transforms, "entities": entities, "tables": tables}


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _place(tf: Any, x: float, y: float) -> tuple[float, float]:
    h = _yaw(tf.rotation)
    c, s = math.cos(h), math.sin(h)
    return tf.translation.x + c * x - s * y, tf.translation.y + s * x + c * y


def _draw_area(ax: Any, entity: Any) -> None:
    """A work area: its outline and its label, in the common frame."""
    for line in entity.lines:
        xs = [p.x for p in line.points] + [line.points[0].x]
        ys = [p.y for p in line.points] + [line.points[0].y]
        ax.plot(xs, ys, color="#4dd966", linewidth=1.6)
    for text in entity.texts:
        ax.text(text.pose.position.x, text.pose.position.y, " " + text.text,
                color="#4dd966", fontsize=9, va="bottom")  # fmt: skip


def _draw_platform(ax: Any, entity: Any, tf: Any) -> None:
    """A platform's footprint and nose (cubes in its own frame), placed by its transform."""
    if tf is None:
        return
    for cube in entity.cubes:
        cx, cy = cube.pose.position.x, cube.pose.position.y
        hx, hy = cube.size.x / 2, cube.size.y / 2
        corners = [(cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy),
                   (cx - hx, cy + hy)]  # fmt: skip
        placed = [_place(tf, x, y) for x, y in corners]
        colour = (cube.color.r, cube.color.g, cube.color.b)
        ax.fill([p[0] for p in placed], [p[1] for p in placed], color=colour, alpha=0.9)
    x, y = tf.translation.x, tf.translation.y
    ax.text(x, y + 0.25, entity.frame_id, color="white", ha="center", fontsize=9)


def draw(seen: dict[str, Any], out: Path) -> None:
    fig = plt.figure(figsize=(13.5, 6.6))
    ax = fig.add_axes((0.04, 0.08, 0.5, 0.8))
    ax.set_facecolor("#16181d")
    ax.grid(color="#3a3d45", linewidth=0.6)
    ax.set_aspect("equal")
    ax.set_title("/tf + /scene in frame fedlab_common (top view, m)")
    for entity in seen["entities"].values():
        if entity.frame_id == "fedlab_common":
            _draw_area(ax, entity)
        else:
            _draw_platform(ax, entity, seen["transforms"].get(entity.frame_id))
    xs = [p.x for e in seen["entities"].values() for line in e.lines for p in line.points]
    ys = [p.y for e in seen["entities"].values() for line in e.lines for p in line.points]
    xs += [t.translation.x for t in seen["transforms"].values()]
    ys += [t.translation.y for t in seen["transforms"].values()]
    if xs:
        ax.set_xlim(min(xs) - 0.5, max(xs) + 0.5)
        ax.set_ylim(min(ys) - 0.5, max(ys) + 0.5)
    lines = ["/fedlab/run"]
    for r in seen["tables"].get("/fedlab/run", []):
        run = "-" if r["run_time"] is None else f"{r['run_time']:.2f} s"
        lines.append(f"  {r['agent']:<16} {r['role']:<9} {r['mode']:<8} run {run:>9}"
                     f"  hold {r['hold']}")  # fmt: skip
    lines += ["", "/fedlab/peers (ms)"]
    for r in seen["tables"].get("/fedlab/peers", []):

        def ms(v: float | None) -> str:
            return "-" if v is None else f"{v:+.3f}"

        lines.append(f"  {r['agent']:<16} -> {r['peer']:<16} offset {ms(r['offset_ms'])}"
                     f"  delay {ms(r['delay_ms'])}  bound {ms(r['error_bound_ms'])}")  # fmt: skip
    fig.text(0.56, 0.88, "\n".join(lines), family="monospace", fontsize=8.5, va="top")
    fig.suptitle("SUBSTITUTE, NOT FOXGLOVE: the messages a foxglove.sdk.v1 client received "
                 "from `fedlab foxglove`, drawn with matplotlib", color="#c0392b")  # fmt: skip
    fig.savefig(out, dpi=100)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", default="ws://127.0.0.1:8765")
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--out", type=Path, default=Path(__file__).with_name("view-substitute.png"))
    args = p.parse_args()
    draw(collect(args.url, args.seconds), args.out)
    print(args.out)


if __name__ == "__main__":
    main()

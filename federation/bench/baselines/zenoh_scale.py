"""Bare zenoh-python agents with a fedlab agent's traffic: the floor of ``fedlab bench
scale``. No fedlab imports: what Zenoh and the interpreter cost, nothing else.

Each agent of a lab runs in this one process, on one session (as ``fedlab bench
scale`` hosts fedlab agents), and per agent declares what a fedlab agent declares
and sends what it sends:

- a liveliness token, and subscribers on every agent's liveliness and on control;
- a sync queryable answering the paper's 64-byte reply (8-byte attachment, ``t2s``);
- pose at 20 Hz: 56 bytes, the 24-byte reference stamp as attachment, source info,
  express and best effort;
- status once a second: ``STATUS_BYTES`` bytes of JSON;
- a follower: one shared subscriber on the leader's pose (each sample decoded once
  for the session, as fedlab's Fanout does, and handed to every follower, which
  gets the time it reached the process); the process's followers, on one clock,
  one sync query to the leader every 0.1 s (sent by the first of them, as fedlab's
  shared sync link); the leader: a sync query to every other agent once a second.

Clocks are the host's monotonic clock, so a follower's latency is its arrival time
minus the stamp. At the end each process writes ``OUT/bare-<lab>.json``: the leader's
sent stamps, each follower's (sent, received) pairs and the sync replies received.

Agents tick in groups of GROUP, the groups staggered over a pose period, and a
group's agents send their sync queries on alternate ticks, as fedlab's workers do
(:func:`federation.runtime.loop.run_together`).

Usage: python zenoh_scale.py ENDPOINT SECONDS OUT STATUS_BYTES GROUP LEADER NAME...
"""

from __future__ import annotations

import heapq
import json
import math
import struct
import sys
import threading
import time
import zlib
from pathlib import Path
from typing import Any

import zenoh

FEDERATION = "fedlab/bare"
POSE = struct.Struct("<7d")
REPLY = struct.Struct("<8d")
REQUEST = struct.Struct("<d")
STAMP = struct.Struct("<BBHIdd")
POSE_PERIOD, SYNC_PERIOD, OTHERS_PERIOD, STATUS_PERIOD = 0.05, 0.1, 1.0, 1.0


class BareAgent:
    def __init__(self, session: zenoh.Session, name: str, leader: str, status_bytes: int):
        self.session, self.name, self.leader = session, name, leader
        self.is_leader = name == leader
        self.ref_id = zlib.crc32(leader.encode())
        self.sn = 0
        self.replies = 0
        self.sent: list[float] = []
        self.received: list[tuple[float, float]] = []
        self.status_pad = "x" * status_bytes
        key = f"{FEDERATION}/{name}"
        cb = zenoh.handlers.Callback
        self.pose_pub = session.declare_publisher(
            f"{key}/pose", express=True, reliability=zenoh.Reliability.BEST_EFFORT
        )
        self.status_pub = session.declare_publisher(f"{key}/status")
        self.entities: list[Any] = [
            session.declare_queryable(f"{key}/sync", cb(self.on_query, indirect=False)),
            self.pose_pub,
            self.status_pub,
            session.declare_subscriber(f"{FEDERATION}/@control", cb(self.ignore, indirect=False)),
            session.liveliness().declare_subscriber(
                f"{FEDERATION}/*/*", cb(self.ignore, indirect=False), history=True
            ),
            session.liveliness().declare_token(key),
        ]
        self.queriers: dict[str, Any] = {}
        self.on_reply = cb(self.reply, indirect=False)

    def ignore(self, sample: zenoh.Sample) -> None:
        pass

    def on_query(self, query: zenoh.Query) -> None:
        t2 = time.monotonic()
        payload = query.payload
        (t1,) = REQUEST.unpack(payload.to_bytes() if payload is not None else bytes(8))
        reply = REPLY.pack(t1, t2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        query.reply(query.key_expr, reply, attachment=REQUEST.pack(time.monotonic()))
        query.drop()

    def reply(self, reply: zenoh.Reply) -> None:
        if reply.ok is not None:
            REPLY.unpack(reply.ok.payload.to_bytes())
            self.replies += 1

    def on_pose(self, t: float, arrived: float) -> None:
        """A pose stamped ``t`` that reached the process at ``arrived`` (decoded and
        timed once for the session, as fedlab's Fanout does)."""
        self.received.append((t, arrived))

    def publish_pose(self) -> None:
        now = time.monotonic()
        self.sn += 1
        self.pose_pub.put(
            POSE.pack(now, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            attachment=STAMP.pack(1, 1, 0, self.ref_id, now, 0.0),
            source_info=zenoh.SourceInfo(self.pose_pub.id, self.sn),
        )
        if self.is_leader:
            self.sent.append(now)

    def query(self, peer: str) -> None:
        querier = self.queriers.get(peer)
        if querier is None:
            querier = self.queriers[peer] = self.session.declare_querier(
                f"{FEDERATION}/{peer}/sync",
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=0.5,
                express=True,
            )
            self.entities.append(querier)
        querier.get(self.on_reply, payload=REQUEST.pack(time.monotonic()))

    def publish_status(self) -> None:
        line = json.dumps({"agent": self.name, "replies": self.replies, "pad": self.status_pad})
        self.status_pub.put(line, encoding=zenoh.Encoding.APPLICATION_JSON)

    def close(self) -> None:
        for entity in reversed(self.entities):
            entity.undeclare()


def _config(endpoint: str) -> zenoh.Config:
    """A client of the router at ``endpoint``, with fedlab's nodes' transport settings."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/unicast/lowlatency", "false")  # as fedlab's nodes
    conf.insert_json5("transport/unicast/qos/enabled", "true")
    conf.insert_json5("transport/link/tx/queue/size/data", "16")  # as fedlab's nodes
    conf.insert_json5("connect/timeout_ms", "-1")  # wait for the router, as fedlab agents do
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def _follow(session: zenoh.Session, leader: str, followers: list[BareAgent]) -> Any | None:
    """One shared subscriber per session on the leader's pose, as fedlab's Fanout: each
    sample is decoded once and handed to every follower (none without followers)."""
    if not followers:
        return None

    def deliver(sample: zenoh.Sample) -> None:
        arrived = time.monotonic()
        t = POSE.unpack(sample.payload.to_bytes())[0]
        attachment = sample.attachment
        if attachment is not None:
            STAMP.unpack(attachment.to_bytes())
        for agent in followers:
            agent.on_pose(t, arrived)

    return session.declare_subscriber(
        f"{FEDERATION}/{leader}/pose", zenoh.handlers.Callback(deliver, indirect=False)
    )


def _schedule(agents: int, group: int, t0: float) -> list[tuple[float, int, str]]:
    """The first wakes, a heap of (due, index, task): pose, sync and status per agent, the
    groups spread over a pose period and a group's agents syncing on their own ticks."""
    step = POSE_PERIOD / max(1, math.ceil(agents / group))
    ticks = round(SYNC_PERIOD / POSE_PERIOD)
    wakes: list[tuple[float, int, str]] = []
    for i in range(agents):
        first = t0 + (i // group) * step
        sync = first + (i % group % ticks) * POSE_PERIOD
        wakes += [(first, i, "pose"), (sync, i, "sync"), (first, i, "status")]
    heapq.heapify(wakes)
    return wakes


class _Ticks:
    """The process's agents ticked on one schedule, and what their sync ticks share: the
    followers share one clock, so the first of them queries the leader for all; the
    leader learns the other agents by liveliness and queries each once a second."""

    def __init__(self, session: zenoh.Session, agents: list[BareAgent], leader: str):
        self.agents, self.leader = agents, leader
        self.sender = next((a for a in agents if not a.is_leader), None)
        self.seen: set[str] = set()
        self.others_phase = 0
        self.stop = threading.Event()
        self.watcher = None
        if any(a.is_leader for a in agents):
            self.watcher = session.liveliness().declare_subscriber(
                f"{FEDERATION}/*/*",
                zenoh.handlers.Callback(self.alive, indirect=False),
                history=True,
            )

    def alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.seen.add(str(sample.key_expr).removeprefix(f"{FEDERATION}/"))

    def run(self, seconds: float, group: int) -> None:
        """Tick every agent's tasks for ``seconds``, each task rescheduled a period after
        it was due (or now, if it ran late)."""
        t0 = time.monotonic()
        end = t0 + seconds
        wakes = _schedule(len(self.agents), group, t0)
        while wakes and not self.stop.is_set():
            due, i, task = wakes[0]
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
                continue
            if due >= end:
                break
            period = self.tick(self.agents[i], task)
            heapq.heapreplace(wakes, (max(due + period, time.monotonic()), i, task))

    def tick(self, agent: BareAgent, task: str) -> float:
        """Run ``task`` for ``agent``; returns the task's period."""
        if task == "pose":
            agent.publish_pose()
            return POSE_PERIOD
        if task == "sync":
            self.sync(agent)
            return SYNC_PERIOD
        agent.publish_status()
        return STATUS_PERIOD

    def sync(self, agent: BareAgent) -> None:
        if agent is self.sender:
            agent.query(self.leader)
        elif agent.is_leader:  # every other agent once a second, over ten ticks
            peers = sorted(self.seen - {self.leader})
            for peer in peers[self.others_phase % 10 :: 10]:
                agent.query(peer)
            self.others_phase += 1

    def close(self) -> None:
        if self.watcher is not None:
            self.watcher.undeclare()


def main() -> None:
    endpoint, seconds, out = sys.argv[1], float(sys.argv[2]), Path(sys.argv[3])
    status_bytes, group = int(sys.argv[4]), int(sys.argv[5])
    leader, names = sys.argv[6], sys.argv[7:]
    with zenoh.open(_config(endpoint)) as session:
        agents = [BareAgent(session, name, leader, status_bytes) for name in names]
        followers = [a for a in agents if not a.is_leader]
        subscriber = _follow(session, leader, followers)
        ticks = _Ticks(session, agents, leader)
        ticks.run(seconds, group)
        time.sleep(0.6)  # the last replies
        result = {
            "sent": [t for a in agents for t in a.sent],
            "received": {a.name: a.received for a in followers},
            "replies": {a.name: a.replies for a in agents},
            "seconds": seconds,
        }
        if subscriber is not None:
            subscriber.undeclare()
        ticks.close()
        for agent in agents:
            agent.close()
    lab = names[0].split("/")[0]
    (out / f"bare-{lab}.json").write_text(json.dumps(result))


if __name__ == "__main__":
    main()

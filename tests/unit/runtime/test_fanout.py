"""The shared subscription of co-hosted agents, on a real Zenoh session."""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Callable

import pytest
import zenoh

from federation.core import wire
from federation.fleet.launch import wait_for
from federation.runtime.fanout import Fanout, Received
from federation.runtime.heap import freeze_startup_heap


def test_every_handler_gets_every_sample_even_if_one_raises(session: zenoh.Session) -> None:
    fanout = Fanout(session)
    got: dict[str, list[bytes]] = {"a": [], "b": []}
    done = threading.Event()

    def broken(sample: Received) -> None:
        raise RuntimeError("a handler that raises")

    def handler(name: str) -> Callable[[Received], None]:
        def on(sample: Received) -> None:
            got[name].append(sample.payload())
            if len(got["b"]) == 3:
                done.set()

        return on

    subs = [
        fanout.subscribe("fed/x/pose", handler("a")),
        fanout.subscribe("fed/x/pose", broken),
        fanout.subscribe("fed/x/pose", handler("b")),
    ]
    for i in range(3):
        session.put("fed/x/pose", bytes([i]))
    assert done.wait(5)
    assert got["a"] == got["b"] == [b"\x00", b"\x01", b"\x02"]
    # One Zenoh subscriber for the three handlers; the last one out undeclares it.
    assert len(fanout._subscribers) == 1
    subs[0].undeclare()
    subs[1].undeclare()
    session.put("fed/x/pose", b"\x03")
    assert wait_for(lambda: got["b"][-1:] == [b"\x03"], timeout=5)
    assert got["a"][-1] == b"\x02"  # undeclared: no more samples
    subs[2].undeclare()
    assert fanout._subscribers == {} and fanout._handlers == {}


def test_a_sample_is_decoded_once_for_every_agent(session: zenoh.Session) -> None:
    """Every handler gets the same Received: its pose and stamp decoded once, a
    malformed part raising the same error for each."""
    fanout = Fanout(session)
    seen: list[tuple[Received, object, object]] = []
    done = threading.Event()

    def on(sample: Received) -> None:
        try:
            pose: object = sample.pose()
        except wire.DecodeError as error:
            pose = error
        try:
            stamp: object = sample.stamp()
        except wire.DecodeError as error:
            stamp = error
        seen.append((sample, pose, stamp))
        if len(seen) == 4:
            done.set()

    subs = [fanout.subscribe("fed/x/pose", on), fanout.subscribe("fed/x/pose", on)]
    good = wire.encode_pose(12.5, wire.Pose(x=1.0))
    session.put("fed/x/pose", good, attachment=wire.encode_stamp(7, 12.25, 0.001))
    session.put("fed/x/pose", b"short", attachment=b"junk")
    assert done.wait(5)
    for sub in subs:
        sub.undeclare()
    (a, pose_a, stamp_a), (b, pose_b, stamp_b) = seen[:2]
    assert a is b and pose_a is pose_b and stamp_a is stamp_b  # decoded once
    assert pose_a == wire.PoseSample(12.5, wire.Pose(x=1.0))
    assert stamp_a == wire.RefStamp(7, 12.25, 0.001)
    assert a.size == len(good) and a.key == "fed/x/pose"
    assert a.source() is None  # put without source info
    (c, pose_c, stamp_c), (d, pose_d, _) = seen[2:]
    assert c is d and pose_c is pose_d
    assert isinstance(pose_c, wire.DecodeError) and isinstance(stamp_c, wire.DecodeError)


def test_the_start_up_heap_is_frozen() -> None:
    before = gc.get_freeze_count()
    try:
        freeze_startup_heap()
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()  # the test process keeps collecting as before


# Real time: ticks counted over 1 s of the loop (7 of 20 at nice 10 beside make test's
# real processes, ci141).
@pytest.mark.timing
def test_agents_run_together_on_one_thread(session: zenoh.Session) -> None:
    """Two agents on one session, one thread, one shared pose subscription: each
    ticks at its rate, the follower gets the leader's pose, both stop on time."""
    from federation.runtime.agent import AgentRuntime, run_together
    from schemas.config import AgentConfig

    fanout = Fanout(session)
    leader = AgentRuntime(
        AgentConfig(lab="lab0", name="lead", role="leader", duration=1.0), session, fanout=fanout
    )
    follower = AgentRuntime(
        AgentConfig(lab="lab1", name="f", role="follower", follow="lab0/lead", duration=1.0),
        session,
        fanout=fanout,
    )
    for agent in (leader, follower):
        agent.start()
    started = time.monotonic()
    try:
        run_together([leader, follower], threading.Event(), spread=0.05)
        took = time.monotonic() - started
        assert list(fanout._subscribers) == ["fedlab/default/lab0/lead/pose"]  # shared
    finally:
        for agent in (leader, follower):
            agent.close()
    assert 1.0 <= took < 3.0
    for agent in (leader, follower):
        assert 15 <= len(agent.lateness) <= 25  # 20 Hz for 1 s
    assert follower.counters["pose_received"] >= 10
    assert "lab0/lead" in follower.status().peers  # it synced with its leader
    assert fanout._subscribers == {}  # closed: the last one out undeclared it

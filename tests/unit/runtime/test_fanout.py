"""The shared subscription of co-hosted agents, on a real Zenoh session."""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Iterator

import pytest
import zenoh

from federation.fleet.launch import wait_for
from federation.runtime.fanout import Fanout
from federation.runtime.heap import freeze_startup_heap


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as s:
        yield s


def test_every_handler_gets_every_sample_even_if_one_raises(session: zenoh.Session) -> None:
    fanout = Fanout(session)
    got: dict[str, list[bytes]] = {"a": [], "b": []}
    done = threading.Event()

    def broken(sample: zenoh.Sample) -> None:
        raise RuntimeError("a handler that raises")

    def handler(name: str) -> object:
        def on(sample: zenoh.Sample) -> None:
            got[name].append(sample.payload.to_bytes())
            if len(got["b"]) == 3:
                done.set()

        return on

    subs = [
        fanout.subscribe("fed/x/pose", handler("a")),  # type: ignore[arg-type]
        fanout.subscribe("fed/x/pose", broken),
        fanout.subscribe("fed/x/pose", handler("b")),  # type: ignore[arg-type]
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


def test_the_start_up_heap_is_frozen() -> None:
    before = gc.get_freeze_count()
    try:
        freeze_startup_heap()
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()  # the test process keeps collecting as before


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

"""The shared subscription of co-hosted agents, on a real Zenoh session."""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator

import pytest
import zenoh

from federation.fanout import Fanout
from federation.heap import freeze_startup_heap
from federation.launch import wait_for


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

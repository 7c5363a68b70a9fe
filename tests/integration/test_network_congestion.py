"""An outside subscriber on a lab router keeps receiving after its link congests.

Zenoh 1.10 with QoS off keeps a universal link's messages in one queue and never
clears that queue's congestion mark once set: after the first droppable message
(a pose, a status) that waited out ``wait_before_drop``, the link drops every later
one for good, while queries and replies still pass. In the namespace testbed that
stopped an outside subscriber on Rome's router under WAN loss (docs/deploy.md,
"Transports under loss"); the shipped router configs therefore turn QoS on.

Here the congestion is made on loopback, without a testbed: a raw zenoh-python
subscriber (Zenoh's default config, as a third party connects) on a router started
from ``deploy/routers/kiruna.json5`` is stopped (SIGSTOP) for 3 s while a client
publishes 2 kB samples at up to 2 kHz, so the router's queue to it overflows and
drops; then it is resumed and must receive again. The same run with QoS off on the
router shows the fault (it fails once a Zenoh release fixes the fault: then QoS
may be turned off again).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from loopback import Labs, client_config

from federation.fleet.launch import Fleet, wait_for

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
KEY = "fedlab/default/kiruna/flood/data"
STOPPED = 3.0  # s the subscriber is stopped
FLOOD_LIMIT = 45.0  # s: the publisher stops by then whatever happens


def _flood(endpoint: str, stop: threading.Event, sent: list[int]) -> None:
    """Publish 2 kB samples (droppable: Zenoh's default congestion control) until
    ``stop`` or :data:`FLOOD_LIMIT` seconds."""
    give_up = time.monotonic() + 20.0  # the router may still be starting
    while True:
        try:
            session = zenoh.open(client_config(endpoint))
            break
        except zenoh.ZError:
            if stop.is_set() or time.monotonic() > give_up:
                raise
            time.sleep(0.3)
    with session:
        pub = session.declare_publisher(KEY)
        end = time.monotonic() + FLOOD_LIMIT
        while not stop.is_set() and time.monotonic() < end:
            pub.put(bytes(2000))
            sent[0] += 1
            time.sleep(0.0005)
        pub.undeclare()  # type: ignore[no-untyped-call]


def _received_after_a_stall(
    labs: Labs, fleet: Fleet, tmp: Path, *cfg: str, before_s: float = 4.0
) -> tuple[int, int]:
    """(received in the ``before_s`` s before the stall, received from 3 s to 7 s after
    it)."""
    router = labs.router("kiruna", *cfg, config=ROOT / "deploy" / "routers" / "kiruna.json5")
    out = tmp / "subscriber.json"
    code = (
        "from pathlib import Path; from federation.bench.network import count_samples; "
        f"count_samples({router.endpoint!r}, 'fedlab/**', Path({str(out)!r}), 40)"
    )
    proc = fleet.spawn("subscriber", [sys.executable, "-c", code])

    def received() -> int:
        try:
            return int(json.loads(out.read_text())["counts"].get(KEY, 0))
        except (OSError, ValueError, KeyError):
            return 0

    stop, sent = threading.Event(), [0]
    flood = threading.Thread(target=_flood, args=(router.endpoint, stop, sent), daemon=True)
    flood.start()
    try:
        assert wait_for(lambda: received() > 100, 20.0), "the subscriber never received"
        first = received()
        time.sleep(before_s)
        before = received() - first
        os.kill(proc.pid, signal.SIGSTOP)
        try:
            time.sleep(STOPPED)
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        time.sleep(3.0)  # what was queued before the stall drains first
        resumed = received()
        time.sleep(4.0)
        after = received() - resumed
        # The stall did overflow the router's queue: samples were dropped.
        assert received() < sent[0] - 100, (received(), sent[0])
        return before, after
    finally:
        stop.set()
        flood.join(10.0)
        os.kill(proc.pid, signal.SIGCONT)


def test_an_outside_subscriber_on_a_shipped_router_receives_again_after_congestion(
    labs: Labs, fleet: Fleet, tmp_path: Path
) -> None:
    before, after = _received_after_a_stall(labs, fleet, tmp_path)
    assert before > 100
    assert after > 0.2 * before, f"{after} samples in 4 s after the stall, {before} before it"


# The fault needs the router's queue to the stopped subscriber to be the one that
# congests: on cores shared with other tests the publisher's own link may congest first,
# its drops happen there, and the router's mark is never set (4517 samples after the
# stall in a parallel run). Alone, the queue that overflows is the router's.
@pytest.mark.timing
def test_with_qos_off_the_router_drops_for_good_after_congestion(
    labs: Labs, fleet: Fleet, tmp_path: Path
) -> None:
    """Why the shipped configs turn QoS on: Zenoh 1.10's fault, shown. Here the count
    before the stall only shows the subscriber received (more than 100 samples; 1 s of
    the flood), not a rate the count after it is set against as with QoS on."""
    before, after = _received_after_a_stall(
        labs, fleet, tmp_path, "--cfg", "transport/unicast/qos/enabled:false", before_s=1.0
    )
    assert before > 100
    assert after == 0, f"{after} samples after the stall: Zenoh no longer has the fault"

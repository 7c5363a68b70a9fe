"""An insider with its own valid certificate floods the generated TLS deployment: memory
stays bounded and nothing over the limits crosses to the other lab.

The insider, ``kiruna/evil``, opens one session after another, each with Zenoh's shared
memory on (an attacker's choice: it is the default), and from each sends 1 MB sync
queries to the leader and 1 MB puts on its own pose and status keys. A Zenoh 1.10 process
that accepts shared memory maps each same-host sender's pool (16 MiB) for good, so every
session grew the Kiruna router and the leader by about 16 MB; the generated configs turn
shared memory off and cap each key's message size at the first router
(federation/deploy/limits.py), and cap the rates of an agent's pose and status.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from insider import EVIL, JUNK, KNATTE_SYNC, evil_config, give_up_after, rss_mb
from loopback import FOLLOWER, LEADER, Labs
from test_trust import Federation, make_federation, start_agent, start_routers

from federation.deploy import limits
from schemas.federation import load_federation

pytestmark = pytest.mark.integration

SESSIONS = 10
ROUNDS = 25  # per session: 25 x (1 MB query, two 1 MB puts) at up to 50 Hz, 0.5 s
SMALL_PUTS = 500  # 100-byte poses at up to 500 Hz: five times the cap, for 1 s
GROWTH_MB = 10.0


def open_evil(fed: Federation) -> zenoh.Session:
    """kiruna/evil's session from its generated config, shared memory turned back on."""
    return zenoh.open(evil_config(fed.zenoh_config("kiruna/evil")))


class Watcher:
    """Rome's operator, watching everything kiruna/evil's keys carry into Rome."""

    def __init__(self, fed: Federation):
        conf = zenoh.Config.from_file(str(fed.zenoh_config("rome/ctl", "operators")))
        self.session = zenoh.open(give_up_after(conf))
        self.lock = threading.Lock()
        self.sizes: dict[str, list[int]] = {}
        self.sub = self.session.declare_subscriber(f"{EVIL}/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        size = len(sample.payload) + (len(sample.attachment) if sample.attachment else 0)
        with self.lock:
            self.sizes.setdefault(str(sample.key_expr).rsplit("/", 1)[-1], []).append(size)

    def count(self, topic: str) -> int:
        with self.lock:
            return len(self.sizes.get(topic, []))

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


@pytest.fixture
def watcher_of() -> Iterator[list[Watcher]]:
    made: list[Watcher] = []
    try:
        yield made
    finally:
        for w in made:
            w.close()


def test_an_insiders_sessions_flood_in_bounded_memory_and_nothing_oversized_crosses(
    labs: Labs, tmp_path: Path, watcher_of: list[Watcher]
) -> None:
    fed = make_federation(tmp_path)
    start_routers(labs, fed)
    leader = start_agent(labs, fed, LEADER)
    follower = start_agent(labs, fed, FOLLOWER, "--clock-offset", "26.42")
    follower.wait_samples(LEADER, 20, timeout=30)
    watcher = Watcher(fed)
    watcher_of.append(watcher)
    pids = {
        "router-kiruna": labs.fleet.procs["router-kiruna"].pid,
        "leader": labs.fleet.procs["kiruna-knatte"].pid,
        "router-rome": labs.fleet.procs["router-rome"].pid,
    }
    before = {name: rss_mb(pid) for name, pid in pids.items()}
    served_before = leader.latest()["counters"].get("sync_requests_served", 0)

    sent = 0
    for _ in range(SESSIONS):  # one after another, each its own session
        evil = open_evil(fed)
        try:
            for _ in range(ROUNDS):
                evil.get(KNATTE_SYNC, lambda reply: None, payload=JUNK, timeout=0.2)
                evil.put(f"{EVIL}/pose", JUNK)
                evil.put(f"{EVIL}/status", JUNK)
                sent += 1
                time.sleep(0.02)
        finally:
            evil.close()
    # Every message has reached whoever takes it in: the follower's next status lines
    # come from a second after the flood.
    flood_end = time.monotonic()
    follower.until(lambda line: line["host_monotonic"] > flood_end + 1.0, 10, "after the flood")
    after = {name: rss_mb(pid) for name, pid in pids.items()}
    growth = {name: after[name] - before[name] for name in pids}

    # Small poses at five times the cap: at most the cap crosses.
    evil = open_evil(fed)
    try:
        started = time.monotonic()
        for i in range(SMALL_PUTS):
            evil.put(f"{EVIL}/pose", i.to_bytes(4, "little") + bytes(96))
            time.sleep(0.002)
        took = time.monotonic() - started
    finally:
        evil.close()
    settings = load_federation(tmp_path / "federation.toml").labs["kiruna"].agents["evil"]
    cap = limits.pose_rate_cap(settings.settings)
    assert follower.wait_samples(LEADER, follower.samples(LEADER) + 10, timeout=10)
    crossed = watcher.count("pose")
    line = follower.latest()
    print(
        f"\n{SESSIONS} sessions x {ROUNDS} x (1 MB sync query, 1 MB pose, 1 MB status): "
        + ", ".join(f"{n} {g:+.1f} MB (from {before[n]:.0f})" for n, g in growth.items())
        + f"; seen in Rome per key: {json.dumps({k: len(v) for k, v in watcher.sizes.items()})}"
        + f"; {SMALL_PUTS} small poses in {took:.2f} s, {crossed} crossed (cap {cap:.0f} Hz)"
    )
    assert sent == SESSIONS * ROUNDS
    assert growth["router-kiruna"] <= GROWTH_MB and growth["leader"] <= GROWTH_MB, growth
    assert growth["router-rome"] <= GROWTH_MB, growth
    oversized = {k: [s for s in v if s > limits.SMALL_LIMIT] for k, v in watcher.sizes.items()}
    assert not any(oversized.values()), oversized  # dropped at Kiruna's router
    # The leader never saw a 1 MB query: none of them reached its queryable.
    assert leader.latest()["counters"].get("sync_requests_oversized", 0) == 0
    served = leader.latest()["counters"].get("sync_requests_served", 0)
    assert served > served_before  # the follower's queries, answered throughout
    # Downsampling passes one pose per 1/cap s: what crossed fits the cap over the send.
    assert 1 <= crossed <= cap * took + 2, (crossed, cap, took)
    assert line["hold"] in (None, "waiting"), line["hold"]
    assert follower.alive() and leader.alive()

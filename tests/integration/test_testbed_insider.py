"""The insider's attacks on the generated deployment, in the network testbed (issue 45).

``fedlab deploy generate`` writes the federation from one file naming the testbed's
addresses: Kiruna's router listens on its public address (TLS, and QUIC for the lab
link), Rome's router is on Rome's lab network behind the NAT and dials Kiruna. Each
lab's processes see their lab's generated folder at the root the files name (a bind
mount of their own, as a lab installs it at /etc/fedlab) and run from those files
alone: both routers, the leader ``kiruna/knatte`` and the follower ``rome/pinocchio``,
in a run started by Kiruna's operator. The insider ``kiruna/evil`` (its own valid
Kiruna certificate, shared memory turned back on in its own config) is a process in
Kiruna's namespace; Rome's operator watches the insider's keys from Rome.

1. Ten sessions one after another, each sending 1 MB sync queries to the leader and
   1 MB puts on the insider's own pose and status keys, ``ROUNDS`` rounds at 50 Hz
   at most (``FLOOD_S`` seconds on idle cores): the Kiruna router and the leader grow
   by at most 10 MB each (RSS from /proc, before and after a settle); no query is
   answered, the leader counts none (none reached it) and the packet stage carries
   none of it across the WAN.
2. The insider publishing 1 MB poses at 50 Hz on its own pose key, with poses of the
   largest size passed at 500 Hz and statuses of the largest size at 100 Hz: Rome
   receives nothing over the size caps, and the insider's share of the WAN stays
   under the cap docs/deploy.md states (``limits.pose_rate_cap x 1 KiB +
   limits.status_rate_cap x limits.status_limit`` a second), counted by Rome's
   subscriber and, with the packets' headers, at the packet stage.
3. Through both, the follower keeps syncing and is never held.

``FLOOD_S`` is 0.5 s a session here, 25 rounds: what a session sends does not matter,
its being a new session does (each mapped its sender's 16 MiB shared-memory pool for good
under the old configs: test_insider_flood.py).
``FEDLAB_INSIDER_FLOOD_S=2 pytest -s tests/integration/test_testbed_insider.py`` floods
for the issue's 2 s. Figures are printed with ``-s``. Needs root, nftables and
/dev/net/tun; skips saying which is missing. Every process is stopped by pid and every
namespace removed (checked).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from insider import EVIL, rss_mb
from loopback import FOLLOWER, LEADER, Agent

from federation.core.linkwatch import MAX_STALE
from federation.deploy import limits
from federation.fleet.launch import wait_for
from federation.link.packet import PacketOptions
from federation.runtime.control import START_IN_MIN
from federation.testbed import PREFIX, Testbed, deployment, leftover_namespaces, missing
from federation.testbed.deployment import (
    AGENTS,
    KIRUNA_PORTS,
    Deployment,
    federation_toml,
    locked_and_recording,
    start_agent,
    start_routers,
    start_run,
)
from schemas.federation import load_federation

WHY = missing()
pytestmark = [
    pytest.mark.integration,
    pytest.mark.testbed,
    pytest.mark.scenario,
    pytest.mark.skipif(WHY is not None, reason=f"network testbed: {WHY}"),
]

INSIDER = Path(__file__).with_name("insider.py")
SESSIONS = 10
FLOOD_S = float(os.environ.get("FEDLAB_INSIDER_FLOOD_S", "0.5"))  # a session; the issue: 2
FLOOD_RATE = 50.0  # rounds a second at most: a 1 MB query, a 1 MB pose and a 1 MB status
ROUNDS = round(FLOOD_RATE * FLOOD_S)  # per session, however long the host lets it take
PUBLISH_S = 3.0
INSIDER_NICE = 10  # the insider's own host is not the lab's: on these shared cores its
# processes run behind the lab's (the testbed's LAB_NICE), which still pay for what they
# receive of its floods; at the lab's niceness it starved the leader (a stale hold).
GROWTH_MB = 10.0
STATUS_PERIOD = 0.25  # s between the leader's and the follower's status lines
ONE_WAY = 0.040  # s, the paper's path
WAN = PacketOptions(delay=ONE_WAY, jitter=0.003)


def generate(tmp: Path) -> Deployment:
    """The testbed's federation, each agent locking its sync after 2 s, generated."""
    settings = {name: {"sync_window": 2.0} for name in AGENTS}
    return deployment.generate(tmp, federation_toml(tmp / "runs", settings))


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """A test that leaves a namespace of this process behind fails."""
    mine = f"{PREFIX}{os.getpid()}x"
    yield
    assert leftover_namespaces(mine) == []


def read_json(path: Path) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data


def wait_exit(bed: Testbed, name: str, timeout: float) -> None:
    """Wait for process ``name`` to end by itself with code 0, or fail with its log."""
    proc = bed.fleet.procs[name]
    try:
        code = proc.wait(timeout)
    except subprocess.TimeoutExpired:
        raise AssertionError(
            f"{name} still running after {timeout} s\n{bed.log(name)[-2000:]}"
        ) from None
    assert code == 0, f"{name} exited with {code}\n{bed.log(name)[-3000:]}"


def stage_bytes(bed: Testbed, after: float) -> tuple[float, int]:
    """The stage's first counters written after host monotonic time ``after`` (it
    writes them every second): (the stage's clock, bytes it carried towards Rome)."""
    wall = time.time() - (time.monotonic() - after)  # the file's time is wall clock
    snaps: list[dict[str, Any]] = []

    def written() -> bool:
        if bed.stats_path.stat().st_mtime < wall:
            return False
        snaps[:] = [bed.stage_stats()]
        return bool(snaps[0])

    assert wait_for(written, 5.0, 0.05), f"the stage wrote no counters: {bed.log('stage')[-1000:]}"
    return float(snaps[0]["seconds"]), int(snaps[0]["backward"]["bytes"])


def downsampled(times: list[float], hz: float) -> int:
    """How many of messages sent at ``times`` a downsampling rule of ``hz`` passes, were
    they to reach it as sent: a message passes when ``1/hz`` has gone by since the last
    one passed (Zenoh's ``downsampling`` interceptor), the first at once."""
    passed, last = 0, float("-inf")
    for t in times:
        if t - last >= 1.0 / hz:
            passed, last = passed + 1, t
    return passed


def ready(agent: Agent) -> bool:
    """The agent's last status line says it may start: locked on the reference clock,
    recording."""
    return locked_and_recording(agent.last())


def status_figures(lines: list[dict[str, Any]], since: float, until: float) -> dict[str, Any]:
    """The follower's holds, sync progress and pose age between two host times."""
    window = [line for line in lines if since <= line["host_monotonic"] <= until]
    samples = [
        (line["host_monotonic"], line["peers"].get(LEADER, {}).get("samples", 0)) for line in window
    ]
    gaps, last_t, last_n = [], since, None
    for t, n in samples:
        if last_n is None or n > last_n:
            gaps.append(t - last_t)
            last_t, last_n = t, n
    gaps.append(until - last_t)
    ages = [line["pose_age"] for line in window if line.get("pose_age") is not None]
    return {
        "lines": len(window),
        "holds": sorted({str(line["hold"]) for line in window if line["hold"] is not None}),
        "modes": sorted({line["mode"] for line in window}),
        "exchanges": samples[-1][1] - samples[0][1] if samples else 0,
        "longest_without_exchange_s": max(gaps),
        "pose_age_max_ms": max(ages) * 1e3 if ages else None,
    }


# The follower's pose stays fresher than the stale threshold while the routers spend
# the cores dropping the floods: beside parallel tests the cores were starved instead
# (one stale hold in a loaded run, a session's 25 rounds taking 10 s).
@pytest.mark.timing
def test_an_insiders_floods_and_oversized_samples_in_the_testbed(tmp_path: Path) -> None:
    dep = generate(tmp_path)
    fed = load_federation(tmp_path / "federation.toml")
    status_cap = limits.status_limit(fed)
    evil_settings = fed.labs["kiruna"].agents["evil"].settings
    pose_hz, status_hz = limits.pose_rate_cap(evil_settings), limits.status_rate_cap(evil_settings)
    cap = pose_hz * limits.SMALL_LIMIT + status_hz * status_cap  # bytes/s, docs/deploy.md
    kiruna, rome = dep.binds("kiruna"), dep.binds("rome")
    watched = tmp_path / "watched.json"
    t0 = time.monotonic()
    with Testbed(tmp_path, WAN, kiruna_ports=KIRUNA_PORTS) as bed:
        start_routers(bed, dep)
        agents = {}
        for who in (LEADER, FOLLOWER):
            name = who.split("/")[1]
            status = tmp_path / f"{name}.jsonl"
            start_agent(bed, dep, name, status, ["--status-period", f"{STATUS_PERIOD:g}"])
            agents[who] = Agent(bed.fleet, name, [], who=who, status=status)
        leader, follower = agents[LEADER], agents[FOLLOWER]
        bed.spawn(
            "rome", "watcher",
            [sys.executable, str(INSIDER), "watch", dep.installed("operators", "ctl.json5"),
             str(watched), f"{EVIL}/**"],
            rome,
        )  # fmt: skip
        for agent in agents.values():
            assert wait_for(partial(ready, agent), 40.0), (
                f"{agent.who} not locked on the reference clock and recording within 40 s; "
                f"last status {agent.last()}\n{bed.log(agent.name)[-3000:]}"
            )
        assert wait_for(lambda: read_json(watched).get("ready"), 20.0), bed.log("watcher")[-2000:]
        # Kiruna's operator starts a run: the follower follows the leader's pose.
        # ctl hears both agents within two of their status periods.
        start_run(bed, dep, duration=600, start_in=START_IN_MIN, discover=2 * STATUS_PERIOD)
        follower.until(
            lambda line: line["mode"] == "running" and line["hold"] is None, 20, "following"
        )
        ready_after = time.monotonic() - t0

        # The WAN's own traffic, to set the attacks' bytes against.
        # From the stage's last counters (written within its second), not its next ones.
        base_t0, base_b0 = stage_bytes(bed, time.monotonic() - 1.0)
        time.sleep(2.0)  # a span of the stage's counters, not a wait for an event
        base_t1, base_b1 = stage_bytes(bed, time.monotonic())
        baseline = (base_b1 - base_b0) / (base_t1 - base_t0)  # bytes/s towards Rome

        # 1. Ten sessions flooding.
        pids = {
            name: bed.fleet.procs[name].pid
            for name in ("router-kiruna", "knatte", "router-rome", "pinocchio")
        }
        before = {name: rss_mb(pid) for name, pid in pids.items()}
        served_before = leader.latest()["counters"].get("sync_requests_served", 0)
        flooded = tmp_path / "flood.json"
        flood_start = time.monotonic()
        # The flood's span at the stage begins at the baseline's last counters (written
        # before the flood starts, so the span holds all of it), not at the next ones.
        wan_t0, wan_b0 = base_t1, base_b1
        bed.spawn(
            "kiruna", "flood",
            [sys.executable, str(INSIDER), "flood", dep.installed("agents", "evil.json5"),
             str(flooded), "--sessions", str(SESSIONS), "--rounds", str(ROUNDS),
             "--rate", f"{FLOOD_RATE:g}"],
            kiruna, nice=INSIDER_NICE,
        )  # fmt: skip
        wait_exit(bed, "flood", SESSIONS * (4 * FLOOD_S + 5) + 30)
        flood_end = time.monotonic()
        wan_t1, wan_b1 = stage_bytes(bed, flood_end)
        # Settled: the follower's status lines from a second after the flood.
        follower.until(lambda line: line["host_monotonic"] > flood_end + 1.0, 10, "after the flood")
        after = {name: rss_mb(pid) for name, pid in pids.items()}
        growth = {name: after[name] - before[name] for name in pids}
        flood = read_json(flooded)
        crossed_in_flood = (wan_b1 - wan_b0) - baseline * (wan_t1 - wan_t0)

        # 2. Oversized and largest-passed samples on the insider's own keys.
        published = tmp_path / "publish.json"
        pub_t0, pub_b0 = stage_bytes(bed, time.monotonic())
        bed.spawn(
            "kiruna", "publish",
            [sys.executable, str(INSIDER), "publish", dep.installed("agents", "evil.json5"),
             str(published), "--seconds", f"{PUBLISH_S:g}", "--status-bytes", str(status_cap)],
            kiruna, nice=INSIDER_NICE,
        )  # fmt: skip
        wait_exit(bed, "publish", PUBLISH_S + 30)
        pub = read_json(published)
        pub_t1, pub_b1 = stage_bytes(bed, pub["ended"] + 1.0)  # what was still on its way
        attacks_end = time.monotonic()
        # Rome's subscriber has saved what arrived until a second after the last put.
        assert wait_for(lambda: read_json(watched).get("at", 0) > pub["ended"] + 1.0, 5.0), (
            f"Rome's subscriber saved nothing after the publish: {bed.log('watcher')[-2000:]}"
        )
        seen = read_json(watched)["keys"]
        follower.until(lambda line: line["host_monotonic"] > attacks_end, 5, "after the attacks")
        lines = follower.lines()
        calm = status_figures(lines, flood_start - 3.0, flood_start)
        in_flood = status_figures(lines, flood_start, flood_end)
        held = status_figures(lines, flood_start, attacks_end)
        line = leader.latest()

    # Every process ended on SIGTERM at the testbed's close, none killed or crashed before.
    exits = {name: proc.returncode for name, proc in bed.fleet.procs.items()}
    took = time.monotonic() - t0

    rounds = [s["rounds"] for s in flood["sessions"]]
    lasted = [round(s["ended"] - s["started"], 2) for s in flood["sessions"]]
    sent = sum(rounds)
    answered = sum(s["replies"] for s in flood["sessions"])
    timeouts = sum(s["errors"] for s in flood["sessions"])
    poses, statuses = seen.get("pose", {}), seen.get("status", {})
    span = pub["ended"] - pub["started"]
    arrivals = [t for k in ("pose", "status") for t, _ in seen.get(k, {}).get("arrivals", [])]
    rome_bytes = poses.get("bytes", 0) + statuses.get("bytes", 0)
    sync_counters = {k: v for k, v in line["counters"].items() if "sync" in k}
    wan_rate = ((pub_b1 - pub_b0) - baseline * (pub_t1 - pub_t0)) / span
    passable = downsampled(pub["pose_max_times"], pose_hz)
    print(
        f"\nready in {ready_after:.1f} s; WAN baseline {baseline / 1024:.1f} KiB/s towards Rome"
        f"\n{SESSIONS} sessions x {ROUNDS} x (1 MB sync query, 1 MB pose, 1 MB status) at "
        f"{FLOOD_RATE:g} Hz at most: {sent} rounds in {lasted} s, {answered} answered, "
        f"{timeouts} timeouts; "
        "growth "
        + ", ".join(f"{n} {g:+.1f} MB (from {before[n]:.0f})" for n, g in growth.items())
        + f"; WAN beyond baseline during the flood {crossed_in_flood / 1024:+.1f} KiB"
        f"\npublished in {span:.2f} s: {json.dumps(pub['sent'])}, of the largest poses "
        f"{passable} at most {pose_hz:g} Hz; Rome received pose "
        f"{poses.get('count', 0)} (largest {poses.get('largest', 0)} B), status "
        f"{statuses.get('count', 0)} (largest {statuses.get('largest', 0)} B): "
        f"{rome_bytes / span / 1024:.1f} KiB/s; at the stage beyond baseline "
        f"{wan_rate / 1024:.1f} KiB/s; cap {cap / 1024:.1f} KiB/s "
        f"({pose_hz:g} x {limits.SMALL_LIMIT} B + {status_hz:g} x {status_cap} B)"
        f"\nfollower before: {json.dumps(calm)}\nduring the flood: {json.dumps(in_flood)}"
        f"\nduring both attacks: {json.dumps(held)}"
        f"\nleader's sync counters {json.dumps(sync_counters)}"
        f"; whole test {took:.1f} s"
    )

    # 1. Ten sessions, each flooding; memory bounded; nothing answered, nothing crossed.
    assert flood["finished"] and len(flood["sessions"]) == SESSIONS, flood
    # Each session sent its rounds at the rate its host let it, never faster than the
    # flood's (a 1 MB put waits for its fragments to be queued: on busy cores a round
    # takes longer, and the session with it).
    assert rounds == [ROUNDS] * SESSIONS, rounds
    assert min(lasted) >= (ROUNDS - 1) / FLOOD_RATE, lasted
    assert growth["router-kiruna"] <= GROWTH_MB and growth["knatte"] <= GROWTH_MB, growth
    # Dropped at Kiruna: nothing answered, and every query ended in an error (its
    # timeout; one run counted 419 errors for 417 queries).
    assert answered == 0 and timeouts >= sent, (answered, timeouts, sent)
    assert line["counters"].get("sync_requests_oversized", 0) == 0  # none reached the leader
    assert line["counters"].get("sync_requests_served", 0) > served_before
    assert crossed_in_flood < 1_000_000, crossed_in_flood  # not one 1 MB message

    # 2. Nothing over the size caps in Rome; the insider's share of the WAN under the cap.
    assert pub["sent"]["pose_1mb"] >= 0.5 * 50 * PUBLISH_S, pub
    assert poses.get("largest", 0) <= limits.SMALL_LIMIT, poses.get("largest")
    assert statuses.get("largest", 0) <= status_cap, statuses.get("largest")
    # As many as the cap passes of what the insider sent when it sent it: at niceness 10
    # on shared cores it sends fewer, or late and in bursts, of which one passes; the
    # router, late too, sees some closer together than sent (under two busy loops: 223 of
    # 238, 214 of 224, 230 of 236 crossed; beside three other tests 112 of 129).
    assert poses.get("count", 0) >= 0.6 * passable, ("the cap's poses did not cross", passable)
    # Downsampling passes one message per 1/cap s, the first at once.
    allowed = (pose_hz * span + 2) * limits.SMALL_LIMIT + (status_hz * span + 2) * status_cap
    assert rome_bytes <= allowed, (rome_bytes, allowed)
    assert arrivals and max(arrivals) <= pub["ended"] + 1.0
    # At the stage, with the headers of QUIC, UDP and IP around each message (7 to 8 %
    # more than the payload in four runs): a quarter more at most.
    assert wan_rate <= 1.25 * allowed / span, (wan_rate, allowed / span)

    # 3. The follower: syncing throughout, never held, never on a stale pose.
    assert held["holds"] == [] and held["modes"] == ["running"], held
    assert held["longest_without_exchange_s"] < 1.0, held
    assert held["pose_age_max_ms"] is not None
    assert held["pose_age_max_ms"] < (ONE_WAY + MAX_STALE) * 1e3, held
    assert set(exits.values()) == {0}, exits

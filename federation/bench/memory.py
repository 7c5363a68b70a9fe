"""``fedlab bench memory``: resident memory per agent hosted in one process, beside
bare zenoh-python agents.

For each N, a fresh process opens one Zenoh session (a peer on loopback, no
router: the agents of a process meet through their session), starts a leader and
one follower, and reads its resident memory (the base: interpreter, libraries,
session). It then adds N followers of the leader, as ``fedlab bench scale``'s
workers host them (one shared pose subscription, one clock, shared sync links,
each with a recorder open on its status and received poses), waits until every agent has seen
every other one alive, and reads the memory again. Agents seen but not queried
are where memory would grow with N (were a sync client kept for every agent
seen), so the figure per agent is taken at two or more N. The agents are
started, not run: the figure is what each keeps, before its windows fill (the
recorders' chunks, the sync history); ``fedlab bench scale`` reads the workers'
memory over a run.

The floor, ``bare``: the same N of :class:`federation.bench.baselines.zenoh_scale.BareAgent`
(the scale bench's bare agents: the same declarations per agent, nothing kept per
peer) on one session, measured the same way.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from federation.bench.procfs import rss_mib

__all__ = ["DEFAULT_AGENTS", "MODES", "measure", "run"]

MODES = ("default", "bare")
DEFAULT_AGENTS = (32, 128)
SETTLE = 1.0  # s after the last agent joined, for liveliness news and first messages
SEEN_TIMEOUT = 30.0  # s for every agent to see every other one


def measure(n: int, mode: str, out: Path, status_bytes: int) -> dict[str, Any]:
    """In this process: the base memory, then with ``n`` more agents (see the module);
    ``status_bytes``: a bare agent's status message."""
    import zenoh

    from federation.runtime.heap import freeze_startup_heap

    # Written out, not federation.runtime.session.build_config: that would import
    # fedlab's schemas into the bare floor's process and count them in its base.
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    with zenoh.open(conf) as session:
        if mode == "default":
            add, agents_seen, close = _fedlab(session, out)
        else:
            add, agents_seen, close = _bare(session, status_bytes)
        try:
            for name in ("lead", "f0"):
                add(name)
            freeze_startup_heap()
            time.sleep(SETTLE)
            base = rss_mib(os.getpid())
            for i in range(1, n + 1):
                add(f"f{i}")
            deadline = time.monotonic() + SEEN_TIMEOUT
            while agents_seen() < n + 1 and time.monotonic() < deadline:
                time.sleep(0.1)
            seen = agents_seen()
            if seen < n + 1:  # a reading now would be of agents half set up
                raise RuntimeError(
                    f"{n} agents, {mode}: an agent saw only {seen} of the {n + 1} others "
                    f"after {SEEN_TIMEOUT:.0f} s"
                )
            time.sleep(SETTLE)
            after = rss_mib(os.getpid())
        finally:
            close()
    return {
        "n": n,
        "mode": mode,
        "base_mib": round(base, 2),
        "rss_mib": round(after, 2),
        "kib_per_agent": round((after - base) * 1024 / n, 1),
        "peers_seen": seen,
    }


def _fedlab(session: Any, out: Path) -> tuple[Any, Any, Any]:
    """Add, count and close fedlab agents hosted as the scale bench's workers host them."""
    from federation.bench.scale import BENCH_RECORD_MB
    from federation.runtime.agent import AgentRuntime
    from federation.runtime.clock import ExecClock
    from federation.runtime.fanout import Fanout
    from federation.runtime.links import SyncLinks
    from schemas.config import AgentConfig

    fanout, links, clock = Fanout(session), SyncLinks(), ExecClock()
    agents: list[AgentRuntime] = []

    def add(name: str) -> None:
        leader = name == "lead"
        config = AgentConfig(
            lab="lab0", name=name, role="leader" if leader else "follower",
            follow=None if leader else "lab0/lead", duration=60.0, status_period=1.0,
            record=out / f"{name}.mcap", record_max_mb=BENCH_RECORD_MB,
            record_channels=["/status", "/pose/sent" if leader else "/pose/received"],
        )  # fmt: skip
        agent = AgentRuntime(config, session, clock, fanout=fanout, links=links)
        agent.start()
        agents.append(agent)

    def seen() -> int:
        """The fewest agents alive that any one of them knows of (each agent's peers
        copied first: Zenoh's threads add to them meanwhile)."""
        return min(sum(p.alive for p in list(a.peers.values())) for a in agents)

    def close() -> None:
        for agent in agents:
            agent.close()

    return add, seen, close


def _bare(session: Any, status_bytes: int) -> tuple[Any, Any, Any]:
    """Add and close bare agents (they keep nothing per peer: all are taken as seen)."""
    from federation.bench.baselines.zenoh_scale import BareAgent

    agents: list[Any] = []

    def add(name: str) -> None:
        agents.append(BareAgent(session, f"lab0/{name}", "lab0/lead", status_bytes))

    def close() -> None:
        for agent in agents:
            agent.close()

    return add, lambda: len(agents) - 1, close


def run(counts: list[int], modes: tuple[str, ...] = MODES) -> list[dict[str, Any]]:
    """One fresh process per count and mode (nothing carried over between them)."""
    from federation.bench.scale import STATUS_BYTES

    rows = []
    for n in counts:
        for mode in modes:
            command = [sys.executable, "-m", "federation.bench.memory", "measure", str(n), mode]
            with tempfile.TemporaryDirectory(prefix="fedlab-bench-memory-") as out:
                try:
                    done = subprocess.run(
                        [*command, out, str(STATUS_BYTES)], capture_output=True, text=True,
                        timeout=SEEN_TIMEOUT + 120, check=False,
                    )  # fmt: skip
                except subprocess.TimeoutExpired:
                    raise RuntimeError(
                        f"fedlab bench memory: {n} agents, {mode}: no result after "
                        f"{SEEN_TIMEOUT + 120:.0f} s (the process was stopped)"
                    ) from None
            if done.returncode != 0:
                raise RuntimeError(
                    f"fedlab bench memory: {n} agents, {mode}: exit {done.returncode}: "
                    f"{done.stderr.strip()[-2000:]}"
                )
            rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    return rows


if __name__ == "__main__" and sys.argv[1:2] == ["measure"]:
    print(json.dumps(measure(int(sys.argv[2]), sys.argv[3], Path(sys.argv[4]), int(sys.argv[5]))))

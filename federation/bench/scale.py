"""``fedlab bench scale``: N agents over 4 labs, pose at 20 Hz and sync at 10 Hz.

Four lab routers in a star (``lab0`` listens, the others dial it, as labs behind
firewalls would). Agent 0 (``lab0/a0``) leads; every other agent follows it,
syncs with it at 10 Hz and publishes its own pose at 20 Hz; the leader queries
each of them once a second (the default for agents it does not follow). Each lab
runs its agents in one worker process on one Zenoh session (this machine has 2
cores), as a lab's gateway process would: one shared pose subscription per key
(:class:`federation.runtime.fanout.Fanout`), the start-up heap frozen
(:mod:`federation.runtime.heap`), all agents' loops on one thread
(:func:`federation.runtime.agent.run_together`).

For each N: CPU of all processes (routers and workers, in cores), p50/p99
one-way pose latency leader to followers (host monotonic clock on both ends;
the leader's clock is mapped to it exactly through its status lines), loss
(leader samples sent while a follower listened that it never received), and
sync exchanges completed per second.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from federation.fleet.launch import Fleet, free_port, wait_for
from federation.report.status import clock_line

__all__ = ["DEFAULT_AGENTS", "LABS", "run", "run_one", "worker"]

LABS = 4
SETTLE = 3.0  # s after start before samples count (discovery, routes)
DEFAULT_AGENTS = (2, 8, 16, 32, 64)
"""Agent counts run when none is given."""


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _agents(n: int) -> list[tuple[int, str]]:
    """(lab index, agent name) for n agents, round-robin over the labs."""
    return [(i % LABS, f"lab{i % LABS}/a{i}") for i in range(n)]


def run_one(n: int, seconds: float, out: Path) -> dict[str, Any]:
    """Run ``n`` agents (at least 2: a leader and a follower) for ``seconds``; returns
    ``n``, ``cpu_cores``, ``p50_ms``, ``p99_ms``, ``loss``, ``samples`` and ``sync_per_s``."""
    if n < 2:
        raise ValueError(f"{n} agents: at least 2 are needed (a leader and a follower)")
    out = out / f"n{n}"
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.mcap"):
        old.unlink()
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in range(LABS)]
    agents = _agents(n)
    with Fleet(out / "logs") as fleet:
        for lab, ep in enumerate(endpoints):
            args = ["router", "--lab", f"lab{lab}", "-l", ep]
            if lab:
                args += ["-e", endpoints[0]]
            fleet.start(f"router-lab{lab}", args)
        for lab in range(LABS):
            mine = [name for (i, name) in agents if i == lab]
            if not mine:
                continue
            fleet.spawn(
                f"worker-lab{lab}",
                [sys.executable, "-m", "federation.bench.scale", "worker", endpoints[lab],
                 f"{seconds + SETTLE}", str(out), *mine],
            )  # fmt: skip
        time.sleep(SETTLE)
        cpu0 = {name: _cpu_seconds(p.pid) for name, p in fleet.procs.items()}
        t0 = time.monotonic()
        time.sleep(max(1.0, seconds - 1.0))  # workers run seconds + SETTLE: still alive here
        cpu = sum(_cpu_seconds(p.pid) - cpu0[name] for name, p in fleet.procs.items())
        wall = time.monotonic() - t0
        workers = [name for name in fleet.procs if name.startswith("worker")]
        wait_for(lambda: not any(fleet.alive(w) for w in workers), 60, 0.2)
    return {"n": n, **_score(out, agents, seconds), "cpu_cores": cpu / wall, "seconds": seconds}


def _score(out: Path, agents: list[tuple[int, str]], seconds: float) -> dict[str, Any]:
    from federation.runtime.recorder import read_messages

    leader = agents[0][1]
    lead = read_messages(out / f"{leader.replace('/', '-')}.mcap", ["/status", "/pose/sent"])
    a, b = clock_line(lead["/status"])
    sent_t = np.array([r["t_exec"] for r in lead["/pose/sent"]])
    latencies: list[float] = []
    lost = expected = 0
    syncs = 0
    for _, name in agents[1:]:
        mine = read_messages(out / f"{name.replace('/', '-')}.mcap", ["/status", "/pose/received"])
        got = [
            (r["t"], r["host_monotonic"]) for r in mine["/pose/received"] if r["agent"] == leader
        ]
        if mine["/status"]:
            syncs += mine["/status"][-1]["peers"].get(leader, {}).get("samples", 0)
        if not got:
            expected += len(sent_t)
            lost += len(sent_t)
            continue
        t_recv = np.array([g[0] for g in got])
        first = t_recv.min() + SETTLE  # count from when routes had settled
        window = sent_t[(sent_t >= first) & (sent_t <= t_recv.max())]
        received = set(t_recv.tolist())
        expected += len(window)
        lost += sum(1 for t in window.tolist() if t not in received)
        latencies += [h - (t - a) / b for t, h in got if t >= first]
    lat = np.asarray(latencies) * 1e3 if latencies else np.asarray([np.nan])
    return {
        "p50_ms": float(np.percentile(lat, 50)),
        "p99_ms": float(np.percentile(lat, 99)),
        "loss": lost / expected if expected else float("nan"),
        "samples": len(latencies),
        "sync_per_s": syncs / (seconds + SETTLE),
    }


def run(ns: list[int], seconds: float, out: Path) -> list[dict[str, Any]]:
    """:func:`run_one` for each agent count in ``ns``."""
    return [run_one(n, seconds, out) for n in ns]


# -- worker: several agents in one process ------------------------------------------
def worker(endpoint: str, seconds: float, out: Path, names: list[str]) -> None:
    """Run ``names`` as agents in this process on one session, as a lab's gateway
    process would."""
    import zenoh

    from federation.runtime.agent import AgentRuntime, run_together
    from federation.runtime.fanout import Fanout
    from federation.runtime.heap import freeze_startup_heap
    from federation.runtime.session import build_config
    from schemas.config import AgentConfig, ZenohOptions

    leader = "lab0/a0"
    stop = threading.Event()
    conf = build_config(ZenohOptions(connect=[endpoint]), default_mode="client")
    runtimes: list[AgentRuntime] = []
    with zenoh.open(conf) as session:
        fanout = Fanout(session)
        try:
            for name in names:
                lab, agent = name.split("/")
                role = "leader" if name == leader else "follower"
                config = AgentConfig(
                    lab=lab,
                    name=agent,
                    role=role,
                    follow=None if role == "leader" else leader,
                    sync_with=[] if role == "leader" else [leader],
                    duration=seconds,
                    status_period=1.0,
                    record=out / f"{lab}-{agent}.mcap",
                    # Only what the scores need: recording is work too.
                    record_channels=[
                        "/status", "/pose/sent" if role == "leader" else "/pose/received"
                    ],
                )  # fmt: skip
                runtime = AgentRuntime(config, session, fanout=fanout)
                runtime.start()
                runtimes.append(runtime)
            freeze_startup_heap()
            # One thread for all of them, their ticks spread over a pose period: agents
            # that wake together fight for the interpreter lock all at once.
            timer = threading.Timer(seconds + 30, stop.set)  # a bound, should one hang
            timer.start()
            try:
                run_together(runtimes, stop, spread=0.05)
            finally:
                timer.cancel()
        finally:
            stop.set()
            for runtime in runtimes:
                runtime.close()


if __name__ == "__main__" and sys.argv[1:2] == ["worker"]:
    worker(sys.argv[2], float(sys.argv[3]), Path(sys.argv[4]), sys.argv[5:])

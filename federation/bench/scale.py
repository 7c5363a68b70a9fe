"""``fedlab bench scale``: N agents over 4 labs, pose at 20 Hz and sync at 10 Hz.

Lab routers in a star (``lab0`` listens, the others dial it, as labs behind
firewalls would). Agent 0 (``lab0/a0``) leads and is the reference; every other
agent follows it and publishes its own pose at 20 Hz. Each lab runs its agents in
one worker process on one Zenoh session (this machine has 2 cores), as a lab's
gateway process would: one shared pose subscription per key
(:class:`federation.runtime.fanout.Fanout`), the start-up heap frozen
(:mod:`federation.runtime.heap`), all agents' loops on one thread
(:func:`federation.runtime.agent.run_together`), each agent on its own wake-up, or
in groups that tick on one (``--group``; the bare floor alike).

Three configurations, run one after the other on the same hosting:

- ``default``: no ``sync_with`` anywhere. Each follower syncs with the leader (its
  reference) at 10 Hz and places others' poses by their reference stamps; the
  leader queries every other agent once a second. O(N) sync traffic.
- ``tuned``: every follower's ``sync_with`` names the leader: the same traffic as
  ``default``, whose followers sync with their reference only, not every pair
  (which would be O(N^2)).
- ``bare``: the floor, :mod:`federation.bench.baselines.zenoh_scale`: bare
  zenoh-python agents with the same declarations and messages per agent.

By default the kernel places every process on any core. With ``--pin-routers``
the routers get a core of their own and the workers the others, fedlab's and the
floor's alike (docs/scale.md, "A late pose waits for a core").

For each: CPU of all processes (routers and workers, in cores, and per agent),
p50/p99 one-way pose latency leader to followers (host monotonic clock on both
ends; the leader's clock is mapped to it exactly through its status lines), loss
(leader samples sent while a follower listened that it never received), sync
exchanges completed per second (all agents), and the workers' resident memory
after warm-up and at the end. For fedlab also the stale-pose safe holds the
followers entered in the same window as the loss (a hold is what a follower does
when the leader's pose is late by more than its link watch's threshold) and the
poses each dropped as stale on arrival (late by more than that threshold: they never
reach its controller, and count as lost here), and for
both the leader's largest gap between two poses it published (where a stalled
loop shows): in the steady state, while every follower listened, and over the
whole run (its cold first tick and the wind-down included).
"""

from __future__ import annotations

import json
import os
import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from math import inf
from pathlib import Path
from typing import Any

import numpy as np

from federation.bench.procfs import rss_mib
from federation.core.channels import recording_stem
from federation.fleet.launch import Fleet, free_port, wait_for
from federation.report.status import clock_line
from federation.runtime.cpus import format_cpus, usable_cpus
from schemas.config import ConfigError

__all__ = [
    "DEFAULT_AGENTS",
    "GROUP",
    "LABS",
    "MODES",
    "STATUS_BYTES",
    "hosting_cores",
    "ratios",
    "run",
    "run_one",
    "summary",
    "worker",
]

LABS = 4
MODES = ("default", "tuned", "bare")
STATUS_BYTES = 1500
"""Bytes of a bare agent's status message: about a fedlab follower's status line."""
GROUP = 1
"""Agents of a worker that tick on one wake-up (fedlab's and the bare floor's alike).
One each by default. Groups of 8 (``--group 8``) cost a third less CPU per agent
but send bursts that lose a pose in some runs at 64 agents, which the default
must not do (docs/scale.md, "Wake-ups")."""
BARE = Path(__file__).with_name("baselines") / "zenoh_scale.py"
SETTLE = 3.0
"""s after the workers are started before samples count (discovery, routes), by
default (``--settle``)."""
DEFAULT_AGENTS = (2, 8, 16, 32, 64)
"""Agent counts run when none is given."""


def _stat_cpu(stat: str) -> tuple[float, float]:
    """User and system CPU seconds from a ``/proc/.../stat`` line (a process's or a
    thread's; fields after the parenthesised name, which may hold spaces and ``)``)."""
    fields = stat.rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        return sum(_stat_cpu(f.read()))


def _thread_cpu(pid: int) -> dict[int, tuple[str, float, float]]:
    """Each thread of a process so far: its name, digits folded (Zenoh's ``rx-0``,
    ``rx-1`` -> ``rx-#``; before Python 3.14 Python's threads all carry the
    interpreter's name), its CPU seconds and the part of them in the kernel, by
    thread id (Linux /proc)."""
    out: dict[int, tuple[str, float, float]] = {}
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:  # the process is gone
        return out
    for tid in tasks:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii", errors="replace") as f:
                stat = f.read()
        except OSError:  # the thread ended meanwhile
            continue
        if "(" not in stat or ")" not in stat:
            continue
        name = re.sub(r"\d+", "#", stat[stat.index("(") + 1 : stat.rindex(")")])
        user, system = _stat_cpu(stat)
        out[int(tid)] = (name, user + system, system)
    return out


def _per_thread(
    before: list[dict[int, tuple[str, float, float]]],
    after: list[dict[int, tuple[str, float, float]]],
    agent_seconds: float,
    kernel: bool = False,
) -> dict[str, float]:
    """The workers' CPU by thread name between two readings, in ms per agent-second:
    which threads the extra over the floor lands on (the interpreter's own thread
    runs the agents' loop, ``fedlab-recorder`` the recorders' writer; Zenoh's ``rx-#``
    threads run the callbacks); with ``kernel``, only the part spent in the kernel
    (system calls, sleeps and wake-ups, lock handovers). Taken thread by thread: one
    that started meanwhile counts from zero, one that ended meanwhile is left out (its
    CPU since the first reading is not known), so neither takes from the others of its
    name."""

    def part(reading: tuple[str, float, float]) -> float:
        return reading[2] if kernel else reading[1]

    total: dict[str, float] = {}
    for b, a in zip(before, after, strict=True):
        for tid, reading in a.items():
            name = reading[0]
            spent = part(reading) - (part(b[tid]) if tid in b else 0.0)
            total[name] = total.get(name, 0.0) + spent
    return {k: round(1e3 * v / agent_seconds, 3) for k, v in sorted(total.items()) if v > 0}


def _fields_moved(
    before: list[dict[int, tuple[str, float, float]]],
    after: list[dict[int, tuple[str, float, float]]],
) -> int:
    """How many of the threads' user and system times moved between two readings (of
    the threads :func:`_per_thread` counts): each reading is whole ticks, so each that
    moved may overstate the thread's CPU by up to a tick."""
    moved = 0
    for b, a in zip(before, after, strict=True):
        for tid, (_, spent, system) in a.items():
            _, spent0, system0 = b.get(tid, ("", 0.0, 0.0))
            moved += (system > system0) + (spent - system > spent0 - system0)
    return moved


def hosting_cores() -> tuple[frozenset[int], frozenset[int]]:
    """The routers' core and the workers' cores when the routers are pinned: the first
    core this process may use, and the others (ConfigError with fewer than two)."""
    usable = sorted(usable_cpus())
    if len(usable) < 2:
        raise ConfigError(
            f"--pin-routers: the routers need a core of their own and the workers another; "
            f"this process may use only {format_cpus(usable)}"
        )
    return frozenset(usable[:1]), frozenset(usable[1:])


def _agents(n: int, labs: int = LABS) -> list[tuple[int, str]]:
    """(lab index, agent name) for n agents, round-robin over the labs."""
    return [(i % labs, f"lab{i % labs}/a{i}") for i in range(n)]


def _check(n: int, mode: str, labs: int, group: int) -> None:
    """ValueError for a run that cannot be made, before anything starts."""
    if n < 2:
        raise ValueError(f"{n} agents: at least 2 are needed (a leader and a follower)")
    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: one of {', '.join(MODES)}")
    if labs < 1:
        raise ValueError(f"{labs} labs: at least one is needed")
    if group < 1:
        raise ValueError(f"groups of {group}: at least one agent is needed")


def _start_routers(fleet: Fleet, endpoints: list[str], cores: frozenset[int] | None) -> None:
    """A router per lab listening on its endpoint, every lab but the first dialling the
    first (a star), each on ``cores`` if given: then it returns once each router has
    pinned itself there (a router pins its process as it starts; on busy cores that
    comes after its workers have begun)."""
    names = []
    for lab, ep in enumerate(endpoints):
        args = ["router", "--lab", f"lab{lab}", "-l", ep]
        if lab:
            args += ["-e", endpoints[0]]
        if cores is not None:
            args += ["--cpus", format_cpus(cores)]
        names.append(f"router-lab{lab}")
        fleet.start(names[-1], args)
    if cores is None:
        return

    def pinned(name: str) -> bool:
        try:
            return usable_cpus(fleet.procs[name].pid) == cores
        except OSError:  # it ended: said below
            return False

    for name in names:
        if not wait_for(partial(pinned, name), 30.0, 0.05):
            raise RuntimeError(
                f"{name} (pid {fleet.procs[name].pid}) did not pin itself to cores "
                f"{format_cpus(cores)} within 30 s; its log: {fleet.log_path(name)}"
            )


def _worker_argv(
    mode: str, endpoint: str, seconds: float, out: Path, group: int, leader: str, mine: list[str]
) -> list[str]:
    """The command of a lab's worker process hosting the agents ``mine`` for ``seconds``:
    the bare floor (:data:`BARE`) or fedlab's (:func:`worker`)."""
    if mode == "bare":
        return [sys.executable, str(BARE), endpoint, f"{seconds}", str(out),
                str(STATUS_BYTES), str(group), leader, *mine]  # fmt: skip
    return [sys.executable, "-m", "federation.bench.scale", "worker", endpoint,
            f"{seconds}", str(out), mode, str(group), *mine]  # fmt: skip


@dataclass
class _Measured:
    """What a run's processes cost, measured from the end of the settling on."""

    hosting: dict[str, list[str]]  # the cores the routers and the workers may run on
    workers: list[str]  # the workers' process names
    cpu: dict[str, float]  # CPU seconds by process name
    wall: float  # s the CPU was measured over
    threads: dict[str, float]  # the workers' CPU by thread name, ms per agent-second
    kernel: dict[str, float]  # the part of it in the kernel
    moved: int  # the thread CPU fields that moved (each up to a tick over)
    rss: list[tuple[float, float]]  # (s since the start, the workers' total MiB)


def _sample_rss(
    fleet: Fleet, workers: list[str], seconds: float, t0: float, end: float
) -> list[tuple[float, float]]:
    """Sleep until ``end``, taking the workers' total resident memory every few seconds
    (the first after a quarter of the run)."""
    rss: list[tuple[float, float]] = []
    while (left := end - time.monotonic()) > 0:
        time.sleep(min(5.0, left))
        if time.monotonic() - t0 >= seconds / 4:
            total = sum(rss_mib(fleet.procs[w].pid) for w in workers)
            rss.append((round(time.monotonic() - t0, 1), round(total, 1)))
    return rss


def _measure(fleet: Fleet, seconds: float, n: int) -> _Measured:
    """Measure the fleet's ``n`` agents for about ``seconds``, then wait for the workers
    to end."""
    workers = [name for name in fleet.procs if name.startswith("worker")]
    hosting = {
        kind: sorted({format_cpus(usable_cpus(p.pid)) for name, p in fleet.procs.items()
                      if name.startswith(kind)})
        for kind in ("router", "worker")
    }  # fmt: skip
    cpu0 = {name: _cpu_seconds(p.pid) for name, p in fleet.procs.items()}
    threads0 = [_thread_cpu(fleet.procs[w].pid) for w in workers]
    t0 = time.monotonic()
    end = t0 + max(1.0, seconds - 1.0)  # workers run settle + seconds: still alive then
    rss = _sample_rss(fleet, workers, seconds, t0, end)
    cpu = {name: _cpu_seconds(p.pid) - cpu0[name] for name, p in fleet.procs.items()}
    wall = time.monotonic() - t0
    threads1 = [_thread_cpu(fleet.procs[w].pid) for w in workers]
    measured = _Measured(
        hosting=hosting,
        workers=workers,
        cpu=cpu,
        wall=wall,
        threads=_per_thread(threads0, threads1, wall * n),
        kernel=_per_thread(threads0, threads1, wall * n, kernel=True),
        moved=_fields_moved(threads0, threads1),
        rss=rss,
    )
    wait_for(lambda: not any(fleet.alive(w) for w in workers), 60, 0.2)
    return measured


def run_one(
    n: int,
    seconds: float,
    out: Path,
    mode: str = "default",
    labs: int = LABS,
    group: int = GROUP,
    pin_routers: bool = False,
    settle: float = SETTLE,
) -> dict[str, Any]:
    """Run ``n`` agents (at least 2: a leader and a follower) over ``labs`` labs for
    ``seconds`` in configuration ``mode`` (:data:`MODES`), each worker's agents ticking
    in groups of ``group`` (fedlab and bare alike); with ``pin_routers`` the routers
    run on the first core this process may use (``fedlab router --cpus``) and the
    workers on the others (:func:`hosting_cores`). Samples count from ``settle``
    seconds after the workers are started (each runs ``settle + seconds``). Returns
    ``n``, ``mode``, ``group``, ``pin_routers``, ``settle``, ``cores`` (the cores the
    routers and the workers may run on, as the kernel has them),
    ``cpu_cores`` (all processes), ``cpu_workers_cores``, ``cpu_routers_cores``,
    ``cpu_per_agent`` (all processes' over ``n``), ``worker_threads_ms`` (the
    workers' CPU by thread name, ms per agent-second), ``worker_threads_kernel_ms``
    (the part of it in the kernel),
    ``p50_ms``, ``p99_ms``, ``loss``, ``samples``, ``sync_per_s`` and the workers'
    total ``rss_mib`` sampled every few seconds (the first after a quarter of the run)."""
    _check(n, mode, labs, group)
    router_cores, worker_cores = hosting_cores() if pin_routers else (None, None)
    out = out / f"n{n}-{mode}"
    out.mkdir(parents=True, exist_ok=True)
    for old in [*out.glob("*.mcap"), *out.glob("bare-*.json")]:
        old.unlink()
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in range(labs)]
    agents = _agents(n, labs)
    leader = agents[0][1]
    with Fleet(out / "logs") as fleet:
        _start_routers(fleet, endpoints, router_cores)
        for lab in range(labs):
            mine = [name for (i, name) in agents if i == lab]
            if mine:
                argv = _worker_argv(
                    mode, endpoints[lab], settle + seconds, out, group, leader, mine
                )
                fleet.spawn(f"worker-lab{lab}", argv, cpus=worker_cores)
        time.sleep(settle)
        m = _measure(fleet, seconds, n)
    if mode == "bare":
        scores = _score_bare(out, leader, settle)
    else:
        scores = _score(out, agents, seconds, settle)
    cpu, wall, workers = m.cpu, m.wall, m.workers
    total = sum(cpu.values()) / wall
    return {
        "n": n,
        "labs": labs,
        "mode": mode,
        "group": group,
        "pin_routers": pin_routers,
        "settle": settle,
        "cores": m.hosting,
        **scores,
        "cpu_cores": total,
        "cpu_workers_cores": sum(cpu[w] for w in workers) / wall,
        "cpu_routers_cores": sum(v for k, v in cpu.items() if k not in workers) / wall,
        "cpu_per_agent": total / n,
        "worker_threads_ms": m.threads,
        "worker_threads_kernel_ms": m.kernel,
        # How far above the truth the threads' sum may be: /proc gives each thread's
        # user and system time in whole clock ticks, so each that moved may have moved
        # by up to one tick more than the thread ran.
        "worker_threads_error_ms": round(m.moved * 1e3 / os.sysconf("SC_CLK_TCK") / (wall * n), 3),
        "rss_mib": m.rss,
        "seconds": seconds,
    }


def _latency_and_loss(
    sent: list[float],
    received: list[list[tuple[float, float]]],
    to_host: Any,
    settle: float = SETTLE,
) -> dict[str, Any]:
    """Pose latency (ms) and loss from the leader's sent stamps and each follower's
    (stamp, host arrival) pairs, from ``settle`` seconds after each follower's first
    pose; ``to_host`` maps a leader stamp to host time."""
    sent_t = np.asarray(sent)
    latencies: list[float] = []
    lost_each: list[int] = []
    expected = 0
    for got in received:
        if not got:
            expected += len(sent_t)
            lost_each.append(len(sent_t))
            continue
        t_recv = np.array([g[0] for g in got])
        first = t_recv.min() + settle  # count from when routes had settled
        window = sent_t[(sent_t >= first) & (sent_t <= t_recv.max())]
        arrived = set(t_recv.tolist())
        expected += len(window)
        lost_each.append(sum(1 for t in window.tolist() if t not in arrived))
        latencies += [h - to_host(t) for t, h in got if t >= first]
    lat = np.asarray(latencies) * 1e3 if latencies else np.asarray([np.nan])
    lost = sum(lost_each)
    return {
        "p50_ms": float(np.percentile(lat, 50)),
        "p99_ms": float(np.percentile(lat, 99)),
        "loss": lost / expected if expected else float("nan"),
        "lost": lost_each,
        "expected": expected,
        "samples": len(latencies),
    }


def _score_bare(out: Path, leader: str, settle: float = SETTLE) -> dict[str, Any]:
    sent: list[float] = []
    received: list[list[tuple[float, float]]] = []
    replies = 0
    seconds = 0.0
    for path in sorted(out.glob("bare-*.json")):
        data = json.loads(path.read_text())
        sent += data["sent"]
        received += [[(t, h) for t, h in pairs] for pairs in data["received"].values()]
        replies += sum(data["replies"].values())
        seconds = data["seconds"]
    scores = _latency_and_loss(sent, received, lambda t: t, settle)
    return {
        **scores,
        "sync_per_s": replies / seconds if seconds else float("nan"),
        # Its leader stamps its poses with host time.
        **_pose_gaps(sorted(sent), _listening(received, settle)),
    }


def _score(
    out: Path, agents: list[tuple[int, str]], seconds: float, settle: float = SETTLE
) -> dict[str, Any]:
    from federation.runtime.recorder import read_messages

    leader = agents[0][1]
    lead = read_messages(out / f"{recording_stem(leader)}.mcap", ["/status", "/pose/sent"])
    a, b = clock_line(lead["/status"])
    sent = [r["t_exec"] for r in lead["/pose/sent"]]
    published = [r["host_monotonic"] for r in lead["/pose/sent"]]
    last = [(agents[0][0], lead["/status"][-1])]
    received = []
    holds = []
    dropped = []
    for lab, name in agents[1:]:
        mine = read_messages(out / f"{recording_stem(name)}.mcap", ["/status", "/pose/received"])
        poses = mine["/pose/received"]
        got = [(r["t"], r["host_monotonic"]) for r in poses if r["agent"] == leader]
        received.append(got)
        if mine["/status"]:
            last.append((lab, mine["/status"][-1]))
        if got and published:
            # The same window as the loss: from when routes had settled to the leader's
            # last pose (after it, every follower holds: the run is over).
            start = min(h for _, h in got) + settle
            holds.append(_counted_between(mine["/status"], "stale_holds", start, published[-1]))
            dropped.append(
                _counted_between(mine["/status"], "pose_stale_dropped", start, published[-1])
            )
        else:  # it lost every pose the leader sent: those it dropped are its whole run's
            dropped.append(_counted_between(mine["/status"], "pose_stale_dropped", -inf, inf))
    scores = _latency_and_loss(sent, received, lambda t: (t - a) / b, settle)
    return {
        **scores,
        "sync_per_s": _exchanges(last) / (seconds + settle),
        **_hold_scores(holds),
        "stale_dropped": dropped,
        **_pose_gaps(published, _listening(received, settle)),
    }


def _exchanges(last: list[tuple[int, dict[str, Any]]]) -> float:
    """The sync exchanges completed, from each agent's last status (with its worker's
    lab index): a link counted once per worker and peer.

    A worker's agents share one clock, so one link (one exchange) per peer. Every agent
    on it reports the link's count, but its ``sharing`` only as it was at that status:
    an agent whose duration ends a few ms before another's leaves the link, and the
    one left reports it as its own. So each link counts once, at the largest count any
    of its agents reports: dividing by ``sharing`` would count such a link up to twice."""
    links: dict[tuple[int, str], float] = {}
    for lab, status in last:
        for peer, view in status["peers"].items():
            links[lab, peer] = max(links.get((lab, peer), 0.0), float(view.get("samples", 0)))
    return sum(links.values())


def _counted_between(statuses: list[dict[str, Any]], counter: str, start: float, end: float) -> int:
    """How much a follower's ``counter`` grew between host times ``start`` and ``end``,
    from its status reports (one a second: the window is that coarse, and reaches back
    to the last report before ``start``)."""

    def count(until: float) -> int:
        before = [s for s in statuses if s["host_monotonic"] <= until]
        return int(before[-1]["counters"].get(counter, 0)) if before else 0

    return count(end) - count(start)


def _hold_scores(holds: list[int]) -> dict[str, Any]:
    """``stale_holds``: safe holds entered by all followers together (the leader's pose
    late by more than the link watch's threshold); ``followers_held``: how many
    followers entered at least one."""
    return {"stale_holds": sum(holds), "followers_held": sum(1 for h in holds if h)}


def _pose_gaps(published: list[float], window: tuple[float, float] | None = None) -> dict[str, Any]:
    """The leader's publication gaps (host times of its poses, s) within ``window``
    (host times; None: all of them): the largest (ms) and how many exceeded twice the
    median (a stalled loop: each is a gap every follower sees, whatever the network
    does). ``leader_gap_max_all_ms`` is the largest over all its publications, start-up
    and wind-down included: the first tick runs cold, and the workers that end first
    close their recordings while the others still run."""
    times = np.asarray(published)
    whole = float(np.diff(times).max() * 1e3) if len(times) >= 3 else float("nan")
    scored = times if window is None else times[(times >= window[0]) & (times <= window[1])]
    if len(scored) < 3:
        return {"leader_gap_max_ms": float("nan"), "leader_gaps_over_2x": 0,
                "leader_gap_max_all_ms": whole}  # fmt: skip
    gaps = np.diff(scored)
    return {
        "leader_gap_max_ms": float(gaps.max() * 1e3),
        "leader_gaps_over_2x": int((gaps > 2.0 * float(np.median(gaps))).sum()),
        "leader_gap_max_all_ms": whole,
    }


def _listening(
    received: list[list[tuple[float, float]]], settle: float = SETTLE
) -> tuple[float, float] | None:
    """The host-time window in which every follower was listening (the steady state):
    from when the last to start had its routes settled to the last arrival of the
    first to stop (those that received nothing are counted lost, not here)."""
    listened = [got for got in received if got]
    if not listened:
        return None
    start = max(min(h for _, h in got) for got in listened) + settle
    return start, min(max(h for _, h in got) for got in listened)


def run(
    ns: list[int],
    seconds: float,
    out: Path,
    modes: tuple[str, ...] = MODES,
    labs: int = LABS,
    runs: int = 1,
    group: int = GROUP,
    progress: Callable[[int, int, str], None] | None = None,
    pin_routers: bool = False,
    settle: float = SETTLE,
) -> list[dict[str, Any]]:
    """:func:`run_one` for each of ``runs`` repeats, agent count in ``ns`` and
    configuration in ``modes`` (interleaved, so that the host's load falls on all
    alike); each row gets its repeat's index as ``run``. ``progress(repeat, n, mode)``
    is called before each run (``repeat`` from 0)."""
    if pin_routers:
        hosting_cores()  # fewer than two cores: refused before any run starts
    rows = []
    for k in range(runs):
        for n in ns:
            for mode in modes:
                if progress is not None:
                    progress(k, n, mode)
                row = run_one(n, seconds, out, mode, labs, group, pin_routers, settle)
                rows.append({**row, "run": k})
    return rows


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Median and spread (min, max) over the repeats, per agent count and
    configuration, of CPU per agent, pose p50/p99, loss, sync exchanges per second,
    the leader's largest publication gap (steady state, and over the whole run) and
    (fedlab) the safe holds; and per agent
    count the ratios fedlab over bare (CPU per agent, p99), each taken within one
    repeat, then their median and spread."""

    def spread(values: list[float]) -> dict[str, float]:
        return {"median": float(np.median(values)), "min": min(values), "max": max(values)}

    figures = ("cpu_per_agent", "cpu_cores", "p50_ms", "p99_ms", "loss", "sync_per_s",
               "leader_gap_max_ms", "leader_gap_max_all_ms", "stale_holds")  # fmt: skip
    table: dict[str, Any] = {}
    for n in sorted({r["n"] for r in rows}):
        mine = [r for r in rows if r["n"] == n]
        entry: dict[str, Any] = {}
        for mode in sorted({r["mode"] for r in mine}):
            of = [r for r in mine if r["mode"] == mode]
            entry[mode] = {
                key: spread([r[key] for r in of])
                for key in figures
                if all(key in r for r in of)  # the bare floor has no safe hold
            }
        per_run: dict[str, list[float]] = {}
        for k in sorted({r.get("run", 0) for r in mine}):
            for key, value in ratios([r for r in mine if r.get("run", 0) == k]).get(n, {}).items():
                per_run.setdefault(key, []).append(value)
        entry["ratios"] = {key: spread(values) for key, values in per_run.items()}
        table[str(n)] = entry
    return table


def ratios(rows: list[dict[str, Any]]) -> dict[int, dict[str, float]]:
    """Per agent count: fedlab (each configuration) over the bare floor, for CPU per
    agent and pose p99, from rows of one repeat (:func:`run`)."""
    out: dict[int, dict[str, float]] = {}
    for n in sorted({r["n"] for r in rows}):
        bare = next((r for r in rows if r["n"] == n and r["mode"] == "bare"), None)
        if bare is None:
            continue
        for r in rows:
            if r["n"] == n and r["mode"] != "bare":
                out.setdefault(n, {})[f"cpu_{r['mode']}_over_bare"] = (
                    r["cpu_per_agent"] / bare["cpu_per_agent"]
                )
                out[n][f"p99_{r['mode']}_over_bare"] = r["p99_ms"] / bare["p99_ms"]
    return out


# -- worker: several agents in one process ------------------------------------------
BENCH_RECORD_MB = 64
"""MiB each bench agent's recording may take (a 240 s run's leader writes about 13)."""


def worker(
    endpoint: str, seconds: float, out: Path, mode: str, names: list[str], group: int = GROUP
) -> None:
    """Run ``names`` as agents in this process on one session, as a lab's gateway
    process would, ticking in groups of ``group``."""
    import zenoh

    from federation.runtime.heap import freeze_startup_heap
    from federation.runtime.host import host
    from federation.runtime.session import build_config
    from schemas.config import AgentConfig, ZenohOptions

    leader = "lab0/a0"
    configs = []
    for name in names:
        lab, agent = name.split("/")
        role = "leader" if name == leader else "follower"
        configs.append(AgentConfig(
            lab=lab,
            name=agent,
            role=role,
            follow=None if role == "leader" else leader,
            sync_with=[] if role == "leader" or mode == "default" else [leader],
            duration=seconds,
            status_period=1.0,
            record=out / f"{lab}-{agent}.mcap",
            # Room for the longest run's few MB: every recording on the host promises its
            # limit (2 GiB by default), and 128 of them would leave the last none.
            record_max_mb=BENCH_RECORD_MB,
            # Only what the scores need: recording is work too.
            record_channels=["/status", "/pose/sent" if role == "leader" else "/pose/received"],
        ))  # fmt: skip
    stop = threading.Event()
    timer = threading.Timer(seconds + 30, stop.set)  # a bound once up, should one hang

    def started() -> None:
        freeze_startup_heap()
        timer.start()

    conf = build_config(ZenohOptions(connect=[endpoint]), default_mode="client")
    try:
        with zenoh.open(conf) as session:
            # As ``fedlab host`` runs a lab's agents: one session, one thread in groups
            # spread over a pose period, one clock (so one sync exchange per peer).
            host(configs, session, stop, group=group, spread=0.05, on_started=started)
    finally:
        timer.cancel()
        stop.set()


if __name__ == "__main__" and sys.argv[1:2] == ["worker"]:
    worker(sys.argv[2], float(sys.argv[3]), Path(sys.argv[4]), sys.argv[5], sys.argv[7:],
           int(sys.argv[6]))  # fmt: skip

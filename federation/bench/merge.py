"""``fedlab bench merge``: peak memory and throughput of ``fedlab merge`` on a large
synthetic run, beside a plain streaming read of the same files.

The run is written first: ``agents`` recordings (default 4: a leader, the reference,
and followers) at the agents' real rates and channel mix (pose sent, its ``/tf`` and
``/pose`` in Foxglove's types and the reference at 20 Hz; the truth and, on a follower,
the leader's pose received, at 20 Hz; a follower's sync exchanges at 10 Hz; a status
line a second, as large as a live one; ``started`` and ``done`` events), with the
recorder's schemas, channels, chunk size and compression and its metadata records, each
agent on its own clock (offset and drift) and host wall clock (seconds apart), the
followers' offset estimates moving at each exchange as a filter's do. It is
deterministic from ``seed`` (log times included) and stops once its files hold
``size`` bytes in all.

Each repeat then runs two child processes on the same files, one after the other: the
merge (``fedlab merge RUN_DIR --out FILE``: :func:`federation.cli.main` in a fresh
interpreter) and the
baseline, a plain streaming read of every message of every file with the mcap library
(``make_reader(...).iter_messages(log_time_order=True)``, what the merge's second pass
reads). Of each: the peak resident memory (``VmHWM`` as the child ends: its own since
``exec``; ``ru_maxrss`` would also count the parent's pages it was forked with), its
resident memory sampled from ``/proc`` over the run (the largest of each tenth of the
run: a merge whose memory grows with the messages read shows it there), the wall time
and MiB/s (the recordings' bytes over the wall time). The files were just written:
both read them from the page cache.

The budget (:data:`BUDGET_MIB`, 128 MiB) is fixed, not a share of the run's size, and
comes from what the merge holds (:mod:`federation.report.merge`, its streaming
paragraph): the interpreter and its libraries (62.3 MiB resident once ``fedlab merge``
has imported them), the writer's chunk being built (4 MiB, its message index and the
compressor's buffers) and, per agent, a reorder window of ``REORDER_S`` of its messages
and two blocks of each of its series on disk (about 1 MiB an agent: 79.1, 80.9 and 85.3
MiB peaks for 2, 4 and 8 agents at 100 MiB); at that rate 128 MiB leaves room for
about 40 agents. The sampled tenths show where a merge's memory grows instead.
"""

from __future__ import annotations

import contextlib
import json
import math
import random
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from foxglove.messages import (
    FrameTransform,
    FrameTransforms,
    PoseInFrame,
    Quaternion,
    Timestamp,
    Vector3,
)
from foxglove.messages import Pose as FoxglovePose
from mcap.writer import Writer

from federation.bench.procfs import rss_mib
from federation.core.channels import (
    CHANNEL_FIELDS,
    COMMON_FRAME,
    FOXGLOVE_CHANNELS,
    Channel,
    json_schema,
    recording_stem,
)
from federation.runtime.mcapfile import CHUNK_SIZE, RECORDING_METADATA, as_metadata

__all__ = [
    "BUDGET_MIB",
    "DEFAULT_AGENTS",
    "DEFAULT_REPEATS",
    "DEFAULT_SIZE_MIB",
    "BudgetExceeded",
    "Measurement",
    "agent_names",
    "check",
    "result",
    "run",
    "summary",
    "write_run",
]

DEFAULT_SIZE_MIB = 2048.0  # MiB of recordings in all
DEFAULT_AGENTS = 4
DEFAULT_REPEATS = 3
BUDGET_MIB = 128.0
"""Peak resident memory (MiB) the merge may reach, whatever the run's size (see the
module: the interpreter and libraries, the writer's chunk, per-agent windows)."""
POSE_RATE = 20.0  # Hz, an agent's pose_rate (default)
SYNC_EVERY = 2  # pose ticks between a follower's sync exchanges (sync_period 0.1 s)
STATUS_EVERY = 20  # pose ticks between status lines (status_period 1 s)
START_TICK = 100  # the run starts 5 s in
DELAY = 0.04  # s, one way between the labs
WALL_UTC = 1_800_000_000.0  # s, UTC of the reference clock's zero on a right wall clock
SAMPLE_S = 0.25  # s between the /proc readings of a child's resident memory
_LABS = (
    ("kiruna", "knatte"), ("rome", "pinocchio"), ("madrid", "quijote"), ("tokyo", "astro"),
    ("bremen", "esel"), ("delft", "nijntje"), ("toulouse", "asterix"), ("boston", "paul"),
)  # fmt: skip


class BudgetExceeded(RuntimeError):
    """The merge's peak resident memory passed the budget."""


def agent_names(n: int) -> list[str]:
    """``n`` agents' LAB/NAME; the first is the leader and the reference."""
    if n < 2:
        raise ValueError(f"a run needs 2 agents or more (a leader and a follower), not {n}")
    return [f"{lab}/{name}" for lab, name in _LABS[:n]] + [
        f"lab{i}/platform{i}" for i in range(len(_LABS), n)
    ]


# -- the synthetic run ---------------------------------------------------------------
class _Agent:
    """One agent's recording, written as the recorder writes it (its schemas,
    channels, chunk size, compression, Foxglove pair and metadata records), stamped on
    the agent's own clock, logged on its host's wall clock."""

    def __init__(self, path: Path, agent: str, index: int, names: list[str], seed: int):
        self.agent, self.leader = agent, names[0]
        self.is_leader = index == 0
        rng = random.Random(f"{seed}:{agent}")
        self.rng = rng
        self.ahead = 0.0 if self.is_leader else rng.uniform(-30.0, 30.0)  # own - reference, s
        self.drift = 0.0 if self.is_leader else rng.uniform(-40e-6, 40e-6)  # own rate error
        self.wall_off = 0.0 if self.is_leader else rng.uniform(-3.0, 3.0)  # host wall - UTC, s
        self.host_zero = rng.uniform(1e3, 1e5)  # host monotonic at reference zero, s
        self.error = 0.0  # s, offset estimate minus truth (moves at each exchange)
        self.exchanges = 0
        self.file: IO[bytes] = path.open("wb")
        self.writer = Writer(self.file, chunk_size=CHUNK_SIZE)
        self.writer.start(profile="", library="fedlab")
        self.ids: dict[str, int] = {}
        for channel in CHANNEL_FIELDS:
            topic = str(channel)
            schema_id = self.writer.register_schema(
                name=topic.strip("/").replace("/", "."), encoding="jsonschema",
                data=json.dumps(json_schema(channel)).encode(),
            )  # fmt: skip
            self.ids[topic] = self.writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id,
                metadata={"agent": agent},
            )  # fmt: skip
        for topic, schema in zip(
            FOXGLOVE_CHANNELS, (FrameTransforms.get_schema(), PoseInFrame.get_schema()), strict=True
        ):
            schema_id = self.writer.register_schema(schema.name, schema.encoding, schema.data)
            self.ids[topic] = self.writer.register_channel(
                topic, schema.encoding, schema_id, {"agent": agent}
            )
        self.writer.add_metadata("fedlab.run", {
            "run_id": f"bench-merge-{seed}", "agent": agent, "host": f"host-{agent.split('/')[0]}",
            "utc_start": "2027-01-15T08:00:00+00:00", "experiment_file": "",
            "experiment": "", "command_line": "fedlab bench merge",
        })  # fmt: skip
        self.messages = 0

    def _put(self, topic: str, ns: int, data: bytes) -> None:
        self.writer.add_message(self.ids[topic], ns, data, ns)
        self.messages += 1

    def _json(self, topic: str, ns: int, message: dict[str, Any]) -> None:
        self._put(topic, ns, json.dumps(message).encode())

    def step(self, k: int, last: bool = False) -> None:
        """Pose tick ``k`` (reference time ``k / POSE_RATE``): what the agent records then."""
        rng = self.rng
        t_ref = k / POSE_RATE
        own = self.ahead + t_ref * (1.0 + self.drift)
        host = self.host_zero + t_ref
        ns = round((WALL_UTC + self.wall_off + t_ref + 0.0003) * 1e9)  # the recorder's latency
        pose = _pose(t_ref, rng)
        sent = {"t_exec": own, "host_monotonic": host, **pose}
        self._json(Channel.POSE_SENT, ns, sent)
        tf, shown = _foxglove_pair(ns, self.agent, pose)
        self._put("/tf", ns, tf)
        self._put("/pose", ns, shown)
        run_time = None if k < START_TICK else (k - START_TICK) / POSE_RATE
        mode = "armed" if k < START_TICK else "done" if last else "running"
        self._json(Channel.REFERENCE, ns, {
            "t_exec": own, "host_monotonic": host, "t_sim": t_ref + self.error,
            "run_time": run_time, "heading_ref": pose["heading"] + rng.gauss(0, 0.002),
            "rate_ref": pose["omega"], "mode": mode, "valves_open": rng.randrange(9),
        })  # fmt: skip
        truth = {k2: v + rng.gauss(0, 1e-3) for k2, v in pose.items()}
        self._json(Channel.TRUTH, ns, {"t_exec": own, "host_monotonic": host, **truth})
        if not self.is_leader:
            self._follower(k, t_ref, own, host, ns)
        if k == START_TICK:
            self._event("started", own, host, ns, t_ref)
        if k % STATUS_EVERY == 0:
            self._json(Channel.STATUS, ns, self._status(k, own, host, t_ref, pose, mode))
        if last:
            self._event("done", own, host, ns, t_ref)

    def _follower(self, k: int, t_ref: float, own: float, host: float, ns: int) -> None:
        rng = self.rng
        leader = _pose(t_ref - DELAY, random.Random(k))
        self._json(Channel.POSE_RECEIVED, ns, {
            "agent": self.leader, "t": t_ref - DELAY, "t_recv": own,
            "host_monotonic": host, **leader,
        })  # fmt: skip
        if k % SYNC_EVERY == 0:
            self.exchanges += 1
            self.error = 0.9 * self.error + rng.gauss(0.0, 30e-6)  # a filter's estimate
            delay = DELAY + abs(rng.gauss(0.0, 0.002))
            t1 = own - 2 * delay
            offset = -(self.ahead + t_ref * self.drift) + rng.gauss(0.0, 0.001)
            self._json(Channel.SYNC_EXCHANGE, ns, {
                "peer": self.leader, "t1": t1, "t2": t1 + offset + delay,
                "t3": own, "t2s": None, "offset": offset, "delay": delay,
                "estimate": offset + self.error, "host_monotonic": host,
            })  # fmt: skip

    def _event(self, event: str, own: float, host: float, ns: int, t_ref: float) -> None:
        self._json(Channel.CONTROL, ns, {
            "event": event, "command": None, "at": START_TICK / POSE_RATE, "t_exec": own,
            "t_sim": t_ref, "host_monotonic": host, "mode": "running" if event == "started"
            else "done", "detail": "", "run_time": t_ref - START_TICK / POSE_RATE,
        })  # fmt: skip

    def _status(
        self, k: int, own: float, host: float, t_ref: float, pose: dict[str, float], mode: str
    ) -> dict[str, Any]:
        """A status line as large as a live one (about 1.5 KB)."""
        rng = self.rng
        bound = 0.0 if self.is_leader else 0.0005 + abs(rng.gauss(0.0, 1e-4))
        peers = {} if self.is_leader else {self.leader: {
            "offset": -(self.ahead + t_ref * self.drift) + self.error, "delay": DELAY,
            "error_bound": bound, "bound": bound / 8, "drift_ppm": self.drift * 1e6,
            "last_offset": -self.ahead, "last_delay": DELAY, "locked": True, "alive": True,
            "samples": self.exchanges, "sent": self.exchanges, "timeouts": 0, "rejected": 0,
            "rejected_by_reason": {}, "clock_steps": 0, "sharing": 1, "silent": None,
        }}  # fmt: skip
        return {
            "agent": self.agent, "federation": "default",
            "role": "leader" if self.is_leader else "follower", "reference": self.leader,
            "t_exec": own, "host_monotonic": host, "t_sim": t_ref, "mode": mode,
            "run_time": max(0.0, (k - START_TICK) / POSE_RATE), "run_id": "bench-merge",
            "duration": None, "start_at": START_TICK / POSE_RATE, "frozen_total": 0.0,
            "experiment": "bench", "ready": {
                "platform": True, "platform_detail": "", "recording": True,
                "recording_to": f"runs/bench-merge/{recording_stem(self.agent)}.mcap",
                "reference_locked": True, "reference_bound": bound,
            },
            "commands": [{"command": "start", "issuer": "ctl@bench:1:00000000", "seq": 1,
                          "outcome": "applied", "detail": ""}],
            "platform": self.agent.split("/")[1], "follow": None if self.is_leader else self.leader,
            "hold": None, "pose_age": None if self.is_leader else DELAY,
            "valves_confirmed": None, "pose": list(pose.values()), "peers": peers,
            "loop": {"rate_hz": 100.0, "ticks": 5.0 * k, "late_p50_ms": rng.uniform(0.1, 0.2),
                     "late_p99_ms": rng.uniform(0.2, 3.0), "late_max_ms": rng.uniform(3.0, 9.0)},
            "counters": {"sync_requests_served": k // 2, "control_received": 3,
                         "pose_received": 0 if self.is_leader else k, "closed_held": 0},
            "contested": {}, "workspace": None, "transition": None, "armed": None,
            "rejoin": None, "admit_run": None,
        }  # fmt: skip

    def size(self) -> int:
        return self.file.tell()

    def close(self) -> None:
        self.writer.add_metadata(RECORDING_METADATA, as_metadata({
            "messages": self.messages, "complete": True, "truncated": False, "max_bytes": None,
            "dropped_over_budget": 0, "dropped_queue_full": 0, "unwritable": 0,
            "write_errors": 0, "reserve_bytes": 0,
        }))  # fmt: skip
        self.writer.finish()
        self.file.close()


def _pose(t: float, rng: random.Random) -> dict[str, float]:
    """A platform's pose at reference time ``t`` (s): a slow turn back and forth."""
    heading = 0.4 * math.sin(0.05 * t) + rng.gauss(0.0, 0.002)
    return {
        "x": 0.3 * math.cos(0.01 * t) + rng.gauss(0.0, 0.001),
        "y": 0.3 * math.sin(0.01 * t) + rng.gauss(0.0, 0.001),
        "heading": heading, "vx": rng.gauss(0.0, 0.002), "vy": rng.gauss(0.0, 0.002),
        "omega": 0.02 * math.cos(0.05 * t) + rng.gauss(0.0, 0.001),
    }  # fmt: skip


def _foxglove_pair(ns: int, frame: str, pose: dict[str, float]) -> tuple[bytes, bytes]:
    """The pose sent in Foxglove's types, as the recorder writes it beside ``/pose/sent``."""
    when = Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)
    where = Vector3(x=pose["x"], y=pose["y"], z=0.0)
    half = pose["heading"] / 2
    turn = Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))
    tf = FrameTransform(
        timestamp=when, parent_frame_id=COMMON_FRAME, child_frame_id=frame,
        translation=where, rotation=turn,
    )  # fmt: skip
    shown = PoseInFrame(
        timestamp=when, frame_id=COMMON_FRAME, pose=FoxglovePose(position=where, orientation=turn)
    )
    return FrameTransforms(transforms=[tf]).encode(), shown.encode()


def write_run(
    folder: Path, size_bytes: int, agents: int = DEFAULT_AGENTS, seed: int = 1
) -> dict[str, Any]:
    """Write a synthetic run of ``agents`` recordings into ``folder``, stopping at the
    first second of run time at which they hold ``size_bytes`` or more in all (see the
    module). Returns its size, messages, duration and files."""
    names = agent_names(agents)
    folder.mkdir(parents=True, exist_ok=True)
    writers = [
        _Agent(folder / f"{recording_stem(a)}.mcap", a, i, names, seed) for i, a in enumerate(names)
    ]
    k = 0
    try:
        while True:
            for w in writers:
                w.step(k)
            k += 1
            if (
                k % STATUS_EVERY == 0
                and k > START_TICK
                and sum(w.size() for w in writers) >= size_bytes
            ):
                break
        for w in writers:
            w.step(k, last=True)
    finally:
        for w in writers:
            w.close()
    files = {p.name: p.stat().st_size for p in sorted(folder.glob("*.mcap"))}
    return {
        "agents": names, "seed": seed, "bytes": sum(files.values()),
        "mib": round(sum(files.values()) / 2**20, 2), "files": files,
        "messages": sum(w.messages for w in writers), "duration_s": k / POSE_RATE,
    }  # fmt: skip


# -- measuring -----------------------------------------------------------------------
_HWM = """
def _hwm(path):
    with open("/proc/self/status", encoding="ascii") as f:
        peak = next(line.split()[1] for line in f if line.startswith("VmHWM:"))
    with open(path, "w", encoding="ascii") as f:
        f.write(peak)
"""
"""Writes the process's peak resident memory (KiB, ``VmHWM``: its own since exec) to a
file as it ends (``ru_maxrss`` would count the parent's memory it was forked with)."""
_BASELINE = (
    _HWM
    + """
import sys
from mcap.reader import make_reader
n = size = 0
for path in sys.argv[2:]:
    with open(path, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages(log_time_order=True):
            n += 1
            size += len(message.data)
print(n, size)
_hwm(sys.argv[1])
"""
)
"""The baseline: every message of every recording, streamed in log-time order."""
_MERGE = (
    _HWM
    + """
import sys
from federation.cli import main
code = main(["merge", *sys.argv[2:]])
_hwm(sys.argv[1])
sys.exit(code)
"""
)
"""The merge: ``fedlab merge`` itself, in a process of its own."""


@dataclass
class Measurement:
    """One child process: its peak resident memory and how long it took."""

    what: str
    wall_s: float
    peak_rss_mib: float  # the child's VmHWM as it ends
    rss_tenths_mib: list[float] = field(default_factory=list)  # largest sampled, each tenth
    mib_per_s: float = 0.0

    def row(self) -> dict[str, Any]:
        return {
            "what": self.what, "wall_s": round(self.wall_s, 3),
            "peak_rss_mib": round(self.peak_rss_mib, 2),
            "rss_tenths_mib": [round(v, 1) for v in self.rss_tenths_mib],
            "mib_per_s": round(self.mib_per_s, 3),
        }  # fmt: skip


def _child(what: str, script: str, args: Sequence[str], logs: Path, run_mib: float) -> Measurement:
    """Run ``script`` with ``args`` in a fresh interpreter to its end, reading its memory
    (see the module). Raises RuntimeError with the end of its output when it fails."""
    out, hwm = logs / f"{what}.log", logs / f"{what}.hwm"
    hwm.unlink(missing_ok=True)
    argv = [sys.executable, "-c", script, str(hwm), *args]
    samples: list[tuple[float, float]] = []
    with out.open("wb") as sink:
        start = time.monotonic()
        child = subprocess.Popen(argv, stdout=sink, stderr=subprocess.STDOUT)
        try:
            while child.poll() is None:
                with contextlib.suppress(OSError):  # it ended between the two calls
                    samples.append((time.monotonic() - start, rss_mib(child.pid)))
                time.sleep(SAMPLE_S)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
        took = time.monotonic() - start
    if child.returncode != 0 or not hwm.is_file():
        tail = out.read_text(encoding="utf-8", errors="replace")[-2000:]
        raise RuntimeError(f"{what} failed (exit {child.returncode}): {tail}")
    tenths = [0.0] * 10
    for t, rss in samples:
        i = min(9, int(10 * t / took))
        tenths[i] = max(tenths[i], rss)
    peak = int(hwm.read_text(encoding="ascii")) / 1024
    return Measurement(what, took, peak, tenths, run_mib / took)


def summary(values: Sequence[float]) -> dict[str, float]:
    """Median, min and max."""
    return {
        "median": round(statistics.median(values), 3),
        "min": round(min(values), 3), "max": round(max(values), 3),
    }  # fmt: skip


def run(
    size_mib: float = DEFAULT_SIZE_MIB,
    agents: int = DEFAULT_AGENTS,
    repeats: int = DEFAULT_REPEATS,
    seed: int = 1,
    budget_mib: float = BUDGET_MIB,
    parent: Path | None = None,
    progress: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Write the run into a temporary folder under ``parent`` (default the system's),
    merge it ``repeats`` times beside the baseline, delete it, and return the result.
    ``result["within_budget"]`` says whether every merge's peak stayed within
    ``budget_mib`` (:func:`check` raises when not).

    Raises
    ------
    ValueError
        When the folder has not room for the run and its merged file.
    """
    if size_mib <= 0 or repeats < 1:
        raise ValueError(f"size must be positive and repeats 1 or more: {size_mib}, {repeats}")
    base = Path(parent) if parent is not None else Path(tempfile.gettempdir())
    base.mkdir(parents=True, exist_ok=True)
    need = 2.5 * size_mib * 2**20  # the run, the merged file (about as large), a margin
    free = shutil.disk_usage(base).free
    if free < need:
        raise ValueError(
            f"{base}: {free / 2**30:.1f} GiB free, the run of {size_mib:.0f} MiB and its "
            f"merged file need about {need / 2**30:.1f} GiB (choose --dir elsewhere)"
        )
    folder = Path(tempfile.mkdtemp(prefix="fedlab-bench-merge-", dir=base))
    try:
        run_dir, logs = folder / "run", folder / "logs"
        logs.mkdir()
        progress(f"writing {size_mib:.0f} MiB of recordings, {agents} agents, in {run_dir}")
        start = time.monotonic()
        written = write_run(run_dir, round(size_mib * 2**20), agents, seed)
        written["write_s"] = round(time.monotonic() - start, 1)
        progress(
            f"wrote {written['mib']:.0f} MiB, {written['messages']} messages, "
            f"{written['duration_s']:.0f} s of run in {written['write_s']:.0f} s"
        )
        paths = [str(run_dir / name) for name in written["files"]]
        merged = folder / "merged.mcap"
        rows: list[Measurement] = []
        for i in range(repeats):
            for what, script, args in (
                ("baseline", _BASELINE, paths),
                ("merge", _MERGE, [str(run_dir), "--out", str(merged)]),
            ):
                m = _child(what, script, args, logs, written["mib"])
                progress(
                    f"repeat {i + 1}/{repeats} {what}: {m.wall_s:.1f} s, "
                    f"{m.mib_per_s:.2f} MiB/s, peak {m.peak_rss_mib:.1f} MiB"
                )
                rows.append(m)
            if i == 0:
                written["merged_mib"] = round(merged.stat().st_size / 2**20, 2)
            merged.unlink()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return result(written, rows, budget_mib)


def result(
    written: dict[str, Any], rows: Sequence[Measurement], budget_mib: float
) -> dict[str, Any]:
    """The result file's content: the run, each child's figures, their spreads and
    the merge's against the baseline's of the same repeat."""
    merges = [m for m in rows if m.what == "merge"]
    bases = [m for m in rows if m.what == "baseline"]
    peak = max(m.peak_rss_mib for m in merges)
    pairs = list(zip(merges, bases, strict=True))
    return {
        "run": written,
        "budget_mib": budget_mib,
        "within_budget": peak <= budget_mib,
        "merge": {
            "peak_rss_mib": summary([m.peak_rss_mib for m in merges]),
            "mib_per_s": summary([m.mib_per_s for m in merges]),
            "wall_s": summary([m.wall_s for m in merges]),
        },
        "baseline": {
            "peak_rss_mib": summary([m.peak_rss_mib for m in bases]),
            "mib_per_s": summary([m.mib_per_s for m in bases]),
            "wall_s": summary([m.wall_s for m in bases]),
        },
        "ratios": {  # merge over baseline, repeat by repeat
            "mib_per_s": summary([m.mib_per_s / b.mib_per_s for m, b in pairs]),
            "peak_rss": summary([m.peak_rss_mib / b.peak_rss_mib for m, b in pairs]),
        },
        "rows": [m.row() for m in rows],
    }  # fmt: skip


def check(result: dict[str, Any]) -> None:
    """Raise :class:`BudgetExceeded` when a merge's peak passed the result's budget."""
    peak, budget = result["merge"]["peak_rss_mib"]["max"], result["budget_mib"]
    if peak > budget:
        raise BudgetExceeded(
            f"merge of {result['run']['mib']:.0f} MiB: peak resident memory {peak:.1f} MiB "
            f"exceeds the budget of {budget:.0f} MiB"
        )

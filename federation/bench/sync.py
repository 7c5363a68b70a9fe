"""``fedlab bench sync``: how far each estimator's offset is from the truth.

Live (default): two lab routers linked through ``fedlab link`` with the
scenario's delay, jitter, asymmetry and bursts; a leader and a follower whose
clock is off by the paper's Kiruna-Rome offset and drifts by the scenario's
ppm. The follower records every sync exchange (``--record``, MCAP); both agents'
status messages pair their clock with the host's monotonic clock, which gives
each clock as an exact linear function of host time, hence the true offset at
every exchange.

Offline (``--offline``): the same exchanges drawn from the link model alone, no
processes. Either way the recorded exchanges are replayed through every
estimator, so one run compares them all on identical input; a live agent's own
estimate is the same function of the same exchanges (tests check it).

Replay (``--replay``): exchanges recorded elsewhere, e.g. by ``fedlab bench
network`` in the namespace testbed (a run folder holding ``follower.mcap`` and
``leader.mcap``), or a file of them saved with ``--save`` (gzip JSON: each run's
exchanges and its two clock lines, a few hundred kilobytes for dozens of runs).

Scores: |estimate - truth| at each exchange after the paper's sync phase, as
p50, p95 and max in seconds. A single run holds one draw of the paper's mean
(fixed after the sync phase), so ``restarts`` scores the same recording again
as fresh starts: a new estimator every 10 s on a ``--trial``-second stretch
(60 s), all errors pooled.
"""

from __future__ import annotations

import gzip
import json
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from federation.core import paper
from federation.core.estimators import ESTIMATORS, make_estimator
from federation.core.sync import Exchange
from federation.link.model import LinkModel
from federation.report.status import clock_line
from schemas.link import DirectionConfig, JitterDist

__all__ = [
    "CLOCK_OFFSET",
    "ESTIMATORS",
    "SCENARIOS",
    "SYNC_PHASE",
    "Recording",
    "Scenario",
    "load_recording",
    "load_runs",
    "load_saved",
    "replay",
    "replay_runs",
    "replay_trials",
    "run",
    "run_live",
    "save_recordings",
    "simulate",
]

CLOCK_OFFSET = paper.CLOCK_OFFSET
"""s, the follower's clock offset in a live run (the paper's)."""
SYNC_PHASE = paper.SYNC_PHASE
"""s of exchanges before scoring starts (the paper's sync phase)."""


@dataclass(frozen=True)
class Scenario:
    name: str
    delay_ms: float = paper.ONE_WAY_DELAY * 1e3
    jitter_ms: float = 5.0
    jitter_dist: JitterDist = "normal"
    drift_ppm: float = 0.0
    asymmetry_ms: float = 0.0
    burst_every: float = 0.0  # s; 0: none
    burst_duration: float = 0.0  # s
    burst_extra_ms: float = 0.0
    burst_jitter_factor: float = 1.0
    about: str = ""

    def direction(self) -> DirectionConfig:
        return DirectionConfig(
            delay=self.delay_ms / 1e3,
            jitter=self.jitter_ms / 1e3,
            jitter_dist=self.jitter_dist,
            burst_every=self.burst_every,
            burst_duration=self.burst_duration,
            burst_extra=self.burst_extra_ms / 1e3,
            burst_jitter_factor=self.burst_jitter_factor,
        )

    def link_args(self) -> list[str]:
        args = [
            "--delay-ms", f"{self.delay_ms}",
            "--jitter-ms", f"{self.jitter_ms}",
            "--jitter-dist", self.jitter_dist,
            "--asymmetry-ms", f"{self.asymmetry_ms}",
        ]  # fmt: skip
        if self.burst_every > 0:
            args += [
                "--burst-every", f"{self.burst_every}",
                "--burst-duration", f"{self.burst_duration}",
                "--burst-extra-ms", f"{self.burst_extra_ms}",
            ]  # fmt: skip
        return args


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("paper-like", about="40 ms one way, 5 ms half-normal jitter"),
        Scenario("heavy-tail", jitter_dist="pareto", about="40 ms, Pareto jitter, mean 5 ms"),
        Scenario("drift", jitter_ms=10.0, drift_ppm=50.0, about="40 ms, 10 ms jitter, 50 ppm"),
        Scenario(
            "bursts",
            burst_every=60.0,
            burst_duration=10.0,
            burst_extra_ms=20.0,
            burst_jitter_factor=4.0,
            about="40 ms, 5 ms jitter; every 60 s, 10 s of +20 ms and 4x jitter",
        ),
        Scenario("asymmetry", asymmetry_ms=10.0, about="40 ms out, 50 ms back, 5 ms jitter"),
    )
}


@dataclass
class Recording:
    """Exchanges as the client saw them, and the true offset at any client time."""

    exchanges: list[Exchange]
    truth: Callable[[float], float]
    meta: dict[str, Any] = field(default_factory=dict)


def _errors(
    exchanges: Sequence[Exchange], truth: Callable[[float], float], estimator: str,
    sync_phase: float, start: float | None = None,
) -> list[float]:  # fmt: skip
    """|estimate - truth| at each exchange ``sync_phase`` seconds after ``start``
    (default: the first exchange), from a fresh estimator fed ``exchanges`` in order."""
    est = make_estimator(estimator)
    start = exchanges[0].t3 if start is None else start
    errors = []
    for ex in exchanges:
        est.add(ex)
        if ex.t3 - start >= sync_phase and (offset := est.offset_at(ex.t3)) is not None:
            errors.append(abs(offset - truth(ex.t3)))
    return errors


def _score(errors: list[float]) -> dict[str, float]:
    e = np.asarray(errors)
    return {
        "p50": float(np.percentile(e, 50)),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
        "n": len(errors),
    }


def replay(
    recording: Recording, estimator: str, sync_phase: float = SYNC_PHASE
) -> dict[str, float]:
    """Feed the exchanges to a fresh estimator; score it after the sync phase."""
    if not recording.exchanges:
        raise ValueError("the recording holds no exchange")
    errors = _errors(recording.exchanges, recording.truth, estimator, sync_phase)
    if not errors:
        raise ValueError(f"no exchange after the {sync_phase} s sync phase: run longer")
    return _score(errors)


def replay_trials(
    recording: Recording,
    estimator: str,
    length: float = 60.0,
    every: float = 10.0,
    sync_phase: float = SYNC_PHASE,
) -> dict[str, float]:
    """Score fresh starts: a new estimator on each ``length``-second stretch of the
    recording (one starting every ``every`` seconds), scored after its own sync
    phase, the errors of all pooled.

    The paper's mean holds one value for the whole run, so a single run scores a
    single draw of it (lucky or not); restarting over the recording compares the
    estimators over many draws of the same path.
    """
    exchanges = recording.exchanges
    if not exchanges:
        raise ValueError("the recording holds no exchange")
    t_first, t_last = exchanges[0].t3, exchanges[-1].t3
    if t_last - t_first < length:
        raise ValueError(
            f"a {length} s trial needs a longer recording than {t_last - t_first:.0f} s"
        )
    errors: list[float] = []
    trials, start = 0, t_first
    while start + length <= t_last + 1e-9:
        stretch = [ex for ex in exchanges if start <= ex.t3 < start + length]
        errors += _errors(stretch, recording.truth, estimator, sync_phase, start)
        trials += 1
        start += every
    return {**_score(errors), "trials": trials, "length_s": length, "every_s": every}


def simulate(scenario: Scenario, duration: float, seed: int = 1, period: float = 0.1) -> Recording:
    """Exchanges drawn from the link model alone (true time = client clock)."""
    link = LinkModel(
        scenario.direction(), asymmetry=scenario.asymmetry_ms / 1e3, seed=seed, start=0.0
    )
    rate = 1.0 + scenario.drift_ppm * 1e-6

    def server(t: float) -> float:
        return CLOCK_OFFSET + t * rate

    exchanges = []
    for k in range(int(duration / period)):
        t1 = k * period  # the client's clock is true time here
        arrival = t1 + link.forward.delay(t1)  # the reply leaves on arrival
        exchanges.append(Exchange(t1, server(arrival), arrival + link.backward.delay(arrival)))
    return Recording(exchanges, lambda t: server(t) - t, {"mode": "offline", "seed": seed})


def load_recording(client: Path, server: Path, peer: str = "kiruna/knatte") -> Recording:
    """A live run's exchanges with ``peer`` from the client's MCAP recording, with the
    truth recovered from both agents' recorded status messages."""
    from federation.runtime.recorder import read_messages

    a_s, b_s = clock_line(read_messages(server, ["/status"])["/status"])
    client_messages = read_messages(client, ["/status", "/sync/exchange"])
    a_c, b_c = clock_line(client_messages["/status"])
    exchanges = [
        Exchange(r["t1"], r["t2"], r["t3"], r["t2s"])
        for r in client_messages["/sync/exchange"]
        if r["peer"] == peer
    ]
    return _recording(exchanges, (a_s, b_s, a_c, b_c), {"mode": "live"})


def _recording(
    exchanges: list[Exchange], lines: tuple[float, float, float, float], meta: dict[str, Any]
) -> Recording:
    """A recording whose truth comes from the two clocks' lines against host time:
    ``server = a_s + b_s host`` and ``client = a_c + b_c host``."""
    a_s, b_s, a_c, b_c = lines

    def truth(t_client: float) -> float:
        host = (t_client - a_c) / b_c
        return a_s + b_s * host - t_client

    return Recording(exchanges, truth, {**meta, "clock_lines": list(lines)})


def save_recordings(path: Path, recordings: dict[str, Recording]) -> None:
    """Write named recordings (made by :func:`load_recording`) as gzip JSON."""
    runs = [
        {"name": name, "clock_lines": rec.meta["clock_lines"],
         "exchanges": [[ex.t1, ex.t2, ex.t3, ex.t2s] for ex in rec.exchanges]}
        for name, rec in recordings.items()
    ]  # fmt: skip
    with gzip.open(path, "wt", encoding="utf-8") as f:
        json.dump({"format": "fedlab.sync-recordings/1", "runs": runs}, f)


def load_saved(path: Path) -> dict[str, Recording]:
    """The named recordings of a file written by :func:`save_recordings`."""
    try:
        with gzip.open(path, "rt", encoding="utf-8") as f:
            doc = json.load(f)
        if doc.get("format") != "fedlab.sync-recordings/1":
            raise ValueError(f"format {doc.get('format')!r} is not fedlab.sync-recordings/1")
        return {
            run["name"]: _recording(
                [Exchange(*row) for row in run["exchanges"]],
                tuple(run["clock_lines"]), {"mode": "replay", "source": str(path)},
            )
            for run in doc["runs"]
        }  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: not a file of saved sync recordings ({e})") from e


def load_runs(paths: Iterable[Path]) -> dict[str, Recording]:
    """Recordings by name from run folders (``follower.mcap`` and ``leader.mcap``, as
    ``fedlab bench network`` leaves them; named ``parent/folder``) and saved files."""
    recordings: dict[str, Recording] = {}
    for path in paths:
        if path.is_dir():
            client, server = path / "follower.mcap", path / "leader.mcap"
            if not (client.is_file() and server.is_file()):
                raise ValueError(f"{path}: a run folder needs follower.mcap and leader.mcap")
            recordings[f"{path.parent.name}/{path.name}"] = load_recording(client, server)
        else:
            recordings.update(load_saved(path))
    return recordings


def replay_runs(
    recordings: dict[str, Recording], estimators: Sequence[str]
) -> list[dict[str, Any]]:
    """Every estimator on every recording from its start: one row per pair, with
    :func:`replay`'s scores (the network bench scores the live estimate the same way)."""
    return [
        {"scenario": name, "estimator": est, **replay(rec, est), "mode": "replay",
         "restarts": None}
        for name, rec in recordings.items()
        for est in estimators
    ]  # fmt: skip


def run_live(scenario: Scenario, duration: float, out: Path, seed: int = 1) -> Recording:
    """Routers, link emulator, leader and follower as processes; returns the recording."""
    from federation.fleet.launch import Fleet, free_port, wait_for

    out.mkdir(parents=True, exist_ok=True)
    leader, follower = out / f"{scenario.name}-leader.mcap", out / f"{scenario.name}-follower.mcap"
    kiruna, link, rome = (f"tcp/127.0.0.1:{free_port()}" for _ in range(3))
    with Fleet(out / f"{scenario.name}-logs") as fleet:
        fleet.start("router-kiruna", ["router", "--lab", "kiruna", "-l", kiruna])
        fleet.start(
            "link",
            ["link", "--listen", link, "--to", kiruna, "--seed", str(seed), *scenario.link_args()],
        )
        fleet.start("router-rome", ["router", "--lab", "rome", "-l", rome, "-e", link])
        common = ["--duration", f"{duration + 2}", "--status-period", "0.5"]
        fleet.start(
            "leader",
            ["agent", "--role", "leader", "--lab", "kiruna", "--name", "knatte", "-e", kiruna,
             "--record", str(leader), *common],
        )  # fmt: skip
        fleet.start(
            "follower",
            ["agent", "--role", "follower", "--lab", "rome", "--name", "pinocchio", "-e", rome,
             "--follow", "kiruna/knatte", "--sync-with", "kiruna/knatte",
             "--clock-offset", f"{CLOCK_OFFSET}", "--clock-drift-ppm", f"{scenario.drift_ppm}",
             "--record", str(follower), *common],
        )  # fmt: skip
        wait_for(lambda: not fleet.alive("follower"), timeout=duration + 60, interval=0.5)
        wait_for(lambda: not fleet.alive("leader"), timeout=10, interval=0.2)
    recording = load_recording(follower, leader)
    recording.meta.update({"mode": "live", "seed": seed})
    return recording


def run(
    scenarios: Iterable[Scenario],
    estimators: Sequence[str],
    duration: float,
    offline: bool,
    out: Path,
    seed: int,
    progress: Callable[[str], None] = lambda s: None,
    trial: float = 60.0,
) -> list[dict[str, Any]]:
    """Record each scenario (live, or ``offline`` from the link model) and score every
    estimator on it: one row per (scenario, estimator) with :func:`replay`'s scores and,
    when the recording spans ``trial`` seconds, :func:`replay_trials`' under ``restarts``."""
    results = []
    for scenario in scenarios:
        started = time.monotonic()
        progress(f"{scenario.name}: {'simulating' if offline else 'running'} {duration:.0f} s")
        if offline:
            recording = simulate(scenario, duration, seed)
        else:
            recording = run_live(scenario, duration, out, seed)
        exchanges = recording.exchanges
        span = exchanges[-1].t3 - exchanges[0].t3 if exchanges else 0.0
        for name in estimators:
            score = replay(recording, name)
            restarts = replay_trials(recording, name, trial) if span >= trial else None
            results.append(
                {"scenario": scenario.name, "estimator": name, **score,
                 "mode": recording.meta["mode"], "duration_s": duration,
                 "restarts": restarts}
            )  # fmt: skip
        progress(f"{scenario.name}: {len(recording.exchanges)} exchanges, "
                 f"{time.monotonic() - started:.0f} s")  # fmt: skip
    return results

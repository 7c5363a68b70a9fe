"""``fedlab bench network-formation``: the formation across labs on real network
stacks under real loss, and its transparency ratio.

The formation experiment (deploy/experiments/formation.toml: KNATTE in Kiruna,
PINOCCHIO in Rome and a third lab's platform keeping a triangle around a circling
centre) flies as real agent processes in the network testbed
(:class:`federation.testbed.Testbed`): Kiruna's router listens on its public
address; Rome's router, behind Rome's masquerading gateway and stateful firewall,
dials it over the paper's path (40 ms one way, 3 ms jitter, the packet stage's
random loss); the third lab's router sits on a second host of Rome's lab network
(``rome2``) and dials Kiruna the same way, so both dialling labs cross the lossy
path and Rome reaches the third lab through Kiruna. Each agent runs in its lab's
namespace and attaches to its own lab's router; the routers are the shipped ones
(deploy/routers/) on hosts with deploy/sysctl's TCP settings (``tcp-tuned`` in
:mod:`federation.bench.network`). The run is started with ``fedlab ctl start`` from
Kiruna, as an operator would, the same time after the agents' launch in every run
(:data:`START_AFTER`): KNATTE drifts on its tilted table while it waits.

Each run is scored with the report's own figure
(:func:`federation.report.scenarios.scenario_summary`): every platform's distance
from its slot around the path's centre, from the truth, RMS over the run (m), the
figure :mod:`federation.bench.transparency` flies in simulated time. The ratio

.. math::

    r_k(p) = \\frac{e_k(p)}{e_k(0)}

of repeat :math:`k`'s error at loss :math:`p` to repeat :math:`k`'s error on the same
path with no loss (same seeds, flown in the same invocation, the runs interleaved so a
busy spell of the host falls on every loss level alike) is 1 when the loss does not
show (:func:`ratios`). The whole run's figure takes in its first seconds, where every
platform comes back to its slot from wherever the wait before the start left it (KNATTE
drifts on its tilted table); the same figure over the circle alone, from the end of the
still and ramp phases (:func:`after_ramp`), gets its ratios beside it.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from federation.bench.network import PORT, TRANSPORTS, _router_args
from federation.bench.transparency import ratio
from federation.core import paper
from federation.core.channels import recording_stem
from federation.fleet.demo import SCENARIO_CLOCKS, scenario_experiment
from federation.fleet.launch import wait_for
from federation.link.packet import PacketOptions
from federation.report.load import load_run
from federation.report.scenarios import scenario_summary
from federation.report.status import last_status
from federation.testbed import Testbed, TestbedError
from federation.testbed.topology import parse_sysctl_conf

__all__ = [
    "HOSTS",
    "JITTER",
    "LOSSES",
    "RunFailed",
    "after_ramp",
    "ratios",
    "run",
    "run_one",
]

LOSSES = (0.0, 0.01, 0.05)
"""Loss on the 40 ms path (each way); 0 is every ratio's baseline."""
JITTER = 0.003
"""s: the path's jitter, as in :mod:`federation.bench.network`."""
TRANSPORT = "tcp-tuned"
"""The shipped routers on hosts with the shipped TCP settings."""
HOSTS = {"kiruna": "kiruna", "rome": "rome", "lab3": "rome2"}
"""The testbed host each lab's router and agent run on."""
SYNC_TIMEOUT = 90.0
"""s for every agent to lock its estimate of the leader's clock after its start (three routers and
three agents starting on a shared 2-core host take a while)."""
START_AFTER = 30.0
"""s from the agents' launch to ``fedlab ctl start`` (later only when an agent locks
later: :func:`run_one` says when): every agent locked within 18 s at 0 and 5 % loss
here, on shared cores."""
START_TRIES = 5
"""``fedlab ctl start`` attempts before a run fails: a preflight that finds an agent not
yet within its error bound (a retransmission under loss) is tried again."""


class RunFailed(RuntimeError):
    """A run could not be flown or scored; says which step and why."""


def run_one(
    loss: float,
    seconds: float,
    out: Path,
    seed: int = 1,
    delay: float = paper.ONE_WAY_DELAY,
    start_after: float = START_AFTER,
    sync_window: float | None = None,
) -> dict[str, Any]:
    """One formation run across the testbed with ``loss`` on the path; its figures.

    ``seconds`` of run time (the experiment's 5 s still and 10 s ramp, then the
    circle); ``seed`` seeds the packet stage and the platforms' noise (as
    ``fedlab demo --scenario formation --seed``); the run is started ``start_after`` s
    after the agents' launch, or once every agent is locked if later; ``sync_window``
    (s) is each agent's ``--sync-window`` (None: the agent's default, the paper's 10 s
    sync phase). Raises :class:`RunFailed` (or :class:`~federation.testbed.TestbedError`)
    saying why a run did not complete."""
    out.mkdir(parents=True, exist_ok=True)
    for stale in [
        *out.glob("*.mcap"),
        *out.glob("*.jsonl"),
        out / "run.json",
        out / "ctl-start.txt",
    ]:
        stale.unlink(missing_ok=True)
    spec = scenario_experiment("formation", seconds, True, seed)
    experiment = out / "experiment.json"
    experiment.write_text(json.dumps(spec, indent=1) + "\n", encoding="utf-8")
    path = PacketOptions(delay=delay, jitter=JITTER, loss=loss)
    run_id = f"formation-loss{loss * 100:g}-seed{seed}"
    t = TRANSPORTS[TRANSPORT]
    sysctls: dict[str, str] = {}
    for conf in t.get("sysctl", []):
        sysctls |= parse_sysctl_conf(Path(conf).read_text(encoding="utf-8"))
    with Testbed(
        out, path, kiruna_ports=t["ports"], sysctls=sysctls, seed=seed, rome_hosts=2
    ) as bed:
        timing = _fly(bed, spec, experiment, run_id, out, start_after, sync_window)
        stage = bed.stage_stats()
    meta = _meta(spec, run_id, delay, loss)
    (out / "run.json").write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    summary = scenario_summary(load_run(out))
    formation = summary.get("formation")
    if formation is None:
        raise RunFailed(f"the report has no formation figure ({summary.get('notes')}): {out}")
    return {
        "loss": loss,
        "seed": seed,
        "seconds": seconds,
        "delay_s": delay,
        "jitter_s": JITTER,
        "error_rms_m": formation["error_rms_m"],
        "error_max_m": formation["error_max_m"],
        "error_rms_after_ramp_m": after_ramp(formation, spec),
        "samples": formation["samples"],
        "per_platform": formation["per_platform"],
        "workspace": summary.get("workspace"),
        "counters": {
            a: (last_status(s) or {}).get("counters", {}) for a, s in _status(out, spec).items()
        },
        "stage": stage,
        **timing,
    }


def after_ramp(formation: dict[str, Any], spec: dict[str, Any]) -> float | None:
    """The report's formation error over the circle only: RMS of every platform's slot
    error from the end of the formation's still and ramp phases (its ``series``);
    None when the run ended before."""
    f = spec["formation"]
    begin = float(f.get("still", 0.0)) + float(f.get("ramp", 0.0))
    t = np.asarray(formation["series"]["run_time_s"], dtype=float)
    errors = np.array(list(formation["series"]["error_m"].values()), dtype=float)
    kept = errors[:, t >= begin]
    return float(np.sqrt(np.mean(kept**2))) if kept.size else None


def _status(out: Path, spec: dict[str, Any]) -> dict[str, Path]:
    """Each agent's ``--status-json`` file."""
    return {
        str(p["agent"]): out / f"{recording_stem(str(p['agent']))}.jsonl"
        for p in spec["participants"]
    }


def _fly(
    bed: Testbed,
    spec: dict[str, Any],
    experiment: Path,
    run_id: str,
    out: Path,
    start_after: float,
    sync_window: float | None = None,
) -> dict[str, float]:
    """Routers and agents in their hosts, every agent synchronized, the run started with
    ``fedlab ctl start`` and flown to its end, the agents stopped (each closes its
    recording); s from the first process to every agent locked, from the agents'
    launch to the start command, and of the run from the start command to every agent
    done."""
    started = time.monotonic()
    for lab, host in HOSTS.items():
        # The third lab dials Kiruna as Rome does, from its own host.
        args = _router_args("kiruna" if lab == "kiruna" else "rome", TRANSPORT)
        bed.fedlab(host, f"router-{lab}", [*args, "--lab", lab])
    status = _status(out, spec)
    launched = time.monotonic()
    window = [] if sync_window is None else ["--sync-window", f"{sync_window:g}"]
    for agent in status:
        lab, name = agent.split("/")
        bed.fedlab(
            HOSTS[lab],
            recording_stem(agent),
            ["agent", "--experiment", str(experiment), "--lab", lab, "--name", name,
             "-e", f"tcp/127.0.0.1:{PORT}", "--clock-offset", f"{SCENARIO_CLOCKS[lab]}",
             "--status-period", "0.5", "--status-json", str(status[agent]),
             "--record", str(out / f"{recording_stem(agent)}.mcap"),
             "--runs-dir", str(out / "runs"), *window],
        )  # fmt: skip

    def modes() -> dict[str, Any]:
        return {a: (last_status(s) or {}).get("mode") for a, s in status.items()}

    def locked(line: dict[str, Any] | None) -> bool:
        """Whether an agent counts reference time with its estimate locked, as
        ``ctl start``'s preflight requires (the reference itself is)."""
        if line is None or line.get("t_sim") is None:
            return False
        return line.get("reference") == line.get("agent") or bool(
            (line.get("ready") or {}).get("reference_locked")
        )

    if not wait_for(
        lambda: all(locked(last_status(s)) for s in status.values()), SYNC_TIMEOUT, 0.1
    ):
        raise RunFailed(
            f"not every agent locked to the reference in {SYNC_TIMEOUT:g} s: {_where(out)}"
        )
    synced_after = time.monotonic() - started
    # The same wait before every run: KNATTE's table tilts (its preset's surface
    # anomalies) and it drifts while it waits with its valves shut, so the run's first
    # seconds bring it back from wherever the wait left it.
    time.sleep(max(0.0, start_after - (time.monotonic() - launched)))
    started_at = time.monotonic() - launched
    _start(bed, experiment, run_id, out)
    run_started = time.monotonic()
    deadline = float(spec["start_delay"]) + float(spec["duration"]) + 30.0
    if not wait_for(lambda: set(modes().values()) == {"done"}, deadline, 0.2):
        raise RunFailed(f"the run did not end in {deadline:g} s (modes {modes()}): {_where(out)}")
    for agent in status:
        bed.stop(recording_stem(agent))
    return {
        "synced_after_s": round(synced_after, 2),
        "start_after_launch_s": round(started_at, 2),
        "run_wall_s": round(time.monotonic() - run_started, 2),
    }


def _meta(spec: dict[str, Any], run_id: str, delay: float, loss: float) -> dict[str, Any]:
    """The run's run.json, as the demo writes it: the report reads the experiment and
    the link from it."""
    return {
        "run_id": run_id,
        "scenario": "formation",
        "experiment": spec,
        "leader": spec["participants"][0]["agent"],
        "agents": {
            str(p["agent"]): {
                "role": p["role"],
                "platform": p["platform"],
                "latency_compensation": True,
                "clock_offset": SCENARIO_CLOCKS[str(p["agent"]).split("/")[0]],
                "clock_drift_ppm": 0.0,
            }
            for p in spec["participants"]
        },
        "link": {"delay_ms": delay * 1e3, "jitter_ms": JITTER * 1e3, "jitter_dist": "normal",
                 "loss": loss, "testbed": True},
    }  # fmt: skip


def _where(out: Path) -> str:
    return f"see the logs in {out / 'logs'}"


def _start(bed: Testbed, experiment: Path, run_id: str, out: Path) -> None:
    """``fedlab ctl start`` from Kiruna's host, tried :data:`START_TRIES` times (its
    preflight refuses while an agent's offset estimate is not yet within its bound);
    its output is kept in ``out/ctl-start.txt``."""
    argv = ["ip", "netns", "exec", bed.ns["kiruna"], sys.executable, "-m", "federation",
            "ctl", "start", "--experiment", str(experiment), "-e", f"tcp/127.0.0.1:{PORT}",
            "--run-id", run_id]  # fmt: skip
    log = out / "ctl-start.txt"
    for k in range(START_TRIES):
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=60.0)
        except subprocess.TimeoutExpired:
            raise RunFailed(f"fedlab ctl start: no answer in 60 s; {out}") from None
        with log.open("a", encoding="utf-8") as f:
            f.write(f"-- try {k + 1}: exit {done.returncode}\n{done.stdout}{done.stderr}")
        if done.returncode == 0:
            return
        time.sleep(1.0)  # the estimates settle between tries
    raise RunFailed(f"fedlab ctl start refused {START_TRIES} times: see {log}")


def _spread(values: Sequence[float | None]) -> dict[str, float | None]:
    got = [v for v in values if v is not None]
    if not got:
        return {"median": None, "min": None, "max": None}
    return {"median": statistics.median(got), "min": min(got), "max": max(got)}


def ratios(results: Sequence[dict[str, Any]], figure: str = "error_rms_m") -> list[dict[str, Any]]:
    """Per loss level above 0: each repeat's error at that loss over the same repeat's
    error with no loss (paired by ``repeat``; a repeat missing either has no ratio),
    and their median, min and max; the error is each result's ``figure``.

    ``results`` are run results (:func:`run_one`'s, with ``repeat``; a failed run has
    ``error`` instead of ``error_rms_m``). ValueError, naming the run, when a result
    has no ``loss`` or no ``repeat``, or when two results share both."""
    by: dict[tuple[float, int], float | None] = {}
    for i, r in enumerate(results):
        if "loss" not in r or "repeat" not in r:
            raise ValueError(f"result {i}: needs 'loss' and 'repeat' (has {sorted(r)})")
        key = (float(r["loss"]), int(r["repeat"]))
        if key in by:
            raise ValueError(f"result {i}: a second run at loss {key[0]:g}, repeat {key[1]}")
        by[key] = r.get(figure)
    repeats = sorted({k for _, k in by})
    out = []
    for loss in sorted({p for p, _ in by if p > 0}):
        baseline = [by.get((0.0, k)) for k in repeats]
        errors = [by.get((loss, k)) for k in repeats]
        each = [ratio(e, b) for e, b in zip(errors, baseline, strict=True)]
        out.append(
            {
                "loss": loss,
                "figure": figure,
                "repeats": repeats,
                "baseline_m": baseline,
                "error_m": errors,
                "ratio": each,
                "ratio_stats": _spread(each),
            }
        )
    return out


def run(
    seconds: float,
    repeats: int,
    out: Path,
    losses: Sequence[float] = LOSSES,
    seed: int = 1,
    progress: Callable[[list[dict[str, Any]]], None] | None = None,
) -> dict[str, Any]:
    """Every loss level ``repeats`` times, interleaved (repeat 0 at each loss, then
    repeat 1 ...; repeat ``k`` seeded ``seed + k`` at every loss); the runs and
    :func:`ratios`. A run that fails is kept as ``{"error": ...}`` and the others go on;
    ``progress`` gets the runs so far after each (to save them)."""
    if 0.0 not in losses:
        raise ValueError(f"losses {list(losses)}: 0 (the baseline of every ratio) is missing")
    results: list[dict[str, Any]] = []
    for k in range(repeats):
        for loss in losses:
            where = out / f"loss{loss * 100:g}-{k}"
            head = {"loss": loss, "repeat": k, "seed": seed + k}
            try:
                result = head | run_one(loss, seconds, where, seed + k)
            except (RunFailed, TestbedError) as error:
                result = head | {"error": str(error)}
            results.append(result)
            if progress is not None:
                progress(results)
    return {
        "transport": TRANSPORT,
        "seconds": seconds,
        "repeats": repeats,
        "runs": results,
        "ratios": ratios(results),
        "ratios_after_ramp": ratios(results, "error_rms_after_ramp_m"),
    }

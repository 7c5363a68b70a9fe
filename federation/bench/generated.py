"""``fedlab bench network --deployment generated``: the federation ``fedlab deploy
generate`` writes, flown in the network testbed on a scenario's path and scored as
:mod:`federation.bench.network` scores its own runs (:func:`network.score`).

The bench's own runs start routers from deploy/routers/ with the lab link its
``--transport`` names and agents from flags. These run the generated files alone
(:mod:`federation.testbed.deployment`): Kiruna's router with its TLS listener and the
QUIC mixed-reliability listener :mod:`federation.deploy.lablink` adds, Rome's behind
the NAT dialling it as generated, both with the generated access control, size limits
(``low_pass_filter``), per-agent rate caps (``downsampling``), lease and queues; the
leader ``kiruna/knatte`` and the follower ``rome/pinocchio`` (its clock 26.42 s off)
reach their own lab's router over TLS with their certificate or password, wait for a
start, and record the run under their ``runs_dir``. Kiruna's operator starts the run
(``fedlab ctl start``); Rome's operator identity is the outside subscriber (a client
without credentials is refused by the generated routers). Both agents' status period is
0.5 s, as the bench's own agents'. Lab hosts get deploy/sysctl/90-fedlab-wan.conf, as
docs/deploy.md tells a lab to install it.

Scored from ``settle`` seconds after the follower's first sync exchange in the run's
recording (made when the run is armed, 1.5 s before it starts) to the run's end; the
run lasts ``settle + seconds``, so about ``seconds + 1.5`` are scored. A scenario's
``cut`` is timed from ``settle`` seconds after the start command returns.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import Any

from federation.bench.network import SCENARIOS, SYSCTL, Scenario, score
from federation.core import paper
from federation.fleet.launch import wait_for
from federation.report.status import last_status
from federation.testbed import ADDR, Testbed, TestbedError
from federation.testbed.deployment import (
    AGENTS,
    KIRUNA_PORTS,
    PORT,
    Deployment,
    federation_toml,
    generate,
    locked_and_recording,
    start_agent,
    start_routers,
    start_run,
)
from federation.testbed.topology import parse_sysctl_conf

__all__ = ["READY_TIMEOUT", "SETTLE", "agent_settings", "recording", "run", "run_one"]

SETTLE = 5.0
"""s from the follower's first exchange in the run's recording to the first scored one."""
READY_TIMEOUT = 90.0
"""s for both agents to say they may start (locked on the reference clock, recording):
the 10 s sync window after both routers link, on a loaded 2-core host."""
STATUS_PERIOD = 0.5  # s, as the bench's own agents


def agent_settings() -> dict[str, dict[str, Any]]:
    """The settings the federation file gives each agent (AgentConfig fields)."""
    return {
        "knatte": {"status_period": STATUS_PERIOD},
        "pinocchio": {"status_period": STATUS_PERIOD, "clock_offset": paper.CLOCK_OFFSET},
    }


def recording(runs: Path, name: str) -> Path | None:
    """Agent ``name``'s finished recording of its one run under ``runs``: its MCAP once
    the manifest that names it is written (the recording's last step), else None."""
    lab, _ = AGENTS[name]
    found = sorted((runs / name).glob(f"*/{lab}-{name}.manifest.json"))
    return found[-1].with_name(f"{lab}-{name}.mcap") if found else None


def _all_done(status: dict[str, Path]) -> bool:
    """Every agent's last status says its run is done."""
    return all((last_status(path) or {}).get("mode") == "done" for path in status.values())


def _all_recorded(runs: Path) -> bool:
    return all(recording(runs, name) is not None for name in AGENTS)


def _subscriber_code(dep: Deployment, out: Path, seconds: float) -> str:
    """The outside subscriber on Rome's router, as Rome's operator."""
    config = dep.installed("operators", "ctl.json5")
    key = f"fedlab/{dep.federation().federation}/**"  # what an operator may subscribe to
    return (
        "from pathlib import Path; from federation.bench.network import count_samples; "
        f"count_samples('', {key!r}, Path({str(out)!r}), {seconds:g}, config={config!r})"
    )


def run_one(
    scenario: Scenario,
    seconds: float,
    out: Path,
    seed: int = 1,
    settle: float = SETTLE,
    sysctl: bool = True,
) -> dict[str, Any]:
    """One run of the generated deployment on ``scenario``'s path; the header and the
    scores of :func:`federation.bench.network.score`. Raises :class:`TestbedError`
    (with the process's log) if the agents are not ready or a run is not recorded."""
    out.mkdir(parents=True, exist_ok=True)
    runs = out / "runs"
    for stale in (runs, out / "deployment"):
        shutil.rmtree(stale, ignore_errors=True)
    dep = generate(out / "deployment", federation_toml(runs, agent_settings()))
    sysctls = parse_sysctl_conf(SYSCTL.read_text()) if sysctl else {}
    status = {name: out / f"{name}.jsonl" for name in AGENTS}
    for path in status.values():
        path.unlink(missing_ok=True)
    subscriber = out / "subscriber.json"
    subscriber.unlink(missing_ok=True)
    events: dict[str, Any] = {}
    duration = settle + seconds
    with Testbed(
        out, scenario.path(), kiruna_ports=KIRUNA_PORTS, sysctls=sysctls, seed=seed
    ) as bed:
        start_routers(bed, dep)
        for name in AGENTS:
            start_agent(bed, dep, name, status[name])
        code = _subscriber_code(dep, subscriber, READY_TIMEOUT + duration + 120)
        bed.spawn("rome", "subscriber", [sys.executable, "-c", code], dep.binds("rome"))
        for name in AGENTS:
            if not wait_for(partial(_ready, status[name]), READY_TIMEOUT):
                raise TestbedError(
                    f"{name} not locked on the reference clock and recording within "
                    f"{READY_TIMEOUT:g} s; last status {last_status(status[name])}\n"
                    f"{bed.log(name)[-3000:]}"
                )
        start_run(bed, dep, duration)
        started = time.monotonic()
        if scenario.cut is not None:
            at, length = scenario.cut
            time.sleep(max(0.0, settle + at - (time.monotonic() - started)))
            events["cut_at"] = bed.cut()
            time.sleep(length)  # the cut's length: the scenario's, not a wait for an event
            events["restored_at"] = bed.restore()
        time.sleep(max(0.0, duration - 12 - (time.monotonic() - started)))
        events["nat_probe"] = {
            "rome_host": bed.probe("kiruna", ADDR.rome, PORT, 2.0),
            "rome_gateway": bed.probe("kiruna", ADDR.rome_gw_wan, PORT, 2.0),
        }
        if not wait_for(partial(_all_done, status), duration + 60, 0.5):
            lines = {n: last_status(status[n]) for n in AGENTS}
            raise TestbedError(f"the run did not end (done) within {duration + 60:g} s: {lines}")
        if not wait_for(partial(_all_recorded, runs), 30, 0.2):
            logs = "\n".join(f"{n}: {bed.log(n)[-1500:]}" for n in AGENTS)
            raise TestbedError(f"the run's recordings were not finished under {runs}\n{logs}")
        events["stage"] = bed.stage_stats()
        lab_link = dep.router_config("rome")["connect"]["endpoints"]
    lead, follow = recording(runs, "knatte"), recording(runs, "pinocchio")
    assert lead is not None and follow is not None  # waited for above
    sub = _read_json(subscriber)
    header = {
        "scenario": asdict(scenario),
        "transport": "generated",
        "deployment": "generated",
        "lab_link": lab_link,
        "sysctl": sysctl,
        "cfg": [],
        "seconds": seconds,
        "seed": seed,
        "sync_phase": settle,
    }
    return {**header, **score(follow, lead, events, sub, settle)}


def _ready(status: Path) -> bool:
    return locked_and_recording(last_status(status))


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data


def run(
    names: list[str],
    seconds: float,
    out: Path,
    repeats: int = 1,
    seed: int = 1,
    progress: Callable[[list[dict[str, Any]]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every scenario ``repeats`` times (seeds ``seed``, ``seed+1``...) on the generated
    deployment. A run that fails (:class:`TestbedError`) is kept as ``{"error": ...}``
    and the others go on; ``progress`` gets the results so far after every run."""
    results: list[dict[str, Any]] = []
    for name in names:
        for k in range(repeats):
            scenario = replace(SCENARIOS[name])
            try:
                result = run_one(scenario, seconds, out / f"{name}-generated-{k}", seed + k)
            except TestbedError as error:
                result = {
                    "scenario": asdict(scenario), "transport": "generated",
                    "deployment": "generated", "seconds": seconds, "seed": seed + k,
                    "error": str(error),
                }  # fmt: skip
            results.append(result)
            if progress is not None:
                progress(results)
    return results

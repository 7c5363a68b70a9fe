"""The benchmarks' headline figures as one Markdown table, read from the committed result
files in ``benchmarks/`` (``fedlab bench table``; the README's table is this text, and
``tests/unit/bench/test_bench_table.py`` fails when they differ).

Each row names its file; a figure is never typed by hand. Ranges are min to max over a
file's repeats, medians first; a baseline is measured in the same run as the figure.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["FILES", "Row", "rows", "table_markdown"]

FILES: dict[str, str] = {
    "sync-drift-600s.json": "fedlab bench sync --scenario drift --duration 600 --json",
    "sync-180s.json": (
        "fedlab bench sync --scenario paper-like --scenario heavy-tail --scenario bursts"
        " --scenario asymmetry --duration 180 --json"
    ),
    "latency-60s.json": "fedlab bench latency --seconds 60 --rate 100 --json",
    "scale-16-40s.json": (
        "fedlab bench scale --agents 16 --seconds 40 --mode default --mode bare --runs 3 --json"
    ),
    "scale-64-128-40s.json": (
        "fedlab bench scale --agents 64 --agents 128 --seconds 40 --mode default --mode bare"
        " --runs 3 --json"
    ),
    "scale-256-8labs-150s.json": (
        "fedlab bench scale --agents 256 --labs 8 --seconds 150 --mode default --json"
    ),
    "memory-32-128.json": "fedlab bench memory --agents 32 --agents 128 --json",
    "network-sync-estimator-60s.json": "(root) fedlab bench network --transport tcp-tuned ...",
    "network-sync-estimator-multilink-60s.json": (
        "(root) fedlab bench network --transport multilink ..."
    ),
    "network-generated-loss5-60s.json": (
        "(root) fedlab bench network --deployment generated --scenario loss5 --seconds 60 ..."
    ),
    "scenarios.json": "fedlab bench scenarios --json",
    "network-formation-60s.json": (
        "(root) fedlab bench network-formation --seconds 60 --repeats 3 --json-out ..."
    ),
    "merge-2gib.json": (
        "fedlab bench merge --size 2048 --repeats 1 --json-out benchmarks/merge-2gib.json"
    ),
    "replay-paper.json": "fedlab bench replay --repeats 3 --json-out benchmarks/replay-paper.json",
}
"""The current result of each benchmark, and the command that made it (the full command
of each is in benchmarks/README.md, or inside the file)."""

Row = tuple[str, str, str, str, str]
"""benchmark, figure, fedlab, baseline, file."""


def _load(folder: Path, name: str) -> Any:
    return json.loads((folder / name).read_text(encoding="utf-8"))


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.3f}"


def _spread(values: Iterable[float], fmt: str = "{:.2f}") -> str:
    """Median, and min to max when the values differ."""
    vals = sorted(values)
    med = fmt.format(statistics.median(vals))
    if len(vals) == 1 or vals[0] == vals[-1]:
        return med
    return f"{med} ({fmt.format(vals[0])} to {fmt.format(vals[-1])})"


def _summary(s: dict[str, float], scale: float = 1.0, fmt: str = "{:.2f}") -> str:
    """A bench summary's {median, min, max}, scaled."""
    values = [s["median"] * scale, s["min"] * scale, s["max"] * scale]
    med, lo, hi = (fmt.format(v) for v in values)
    return med if lo == hi else f"{med} ({lo} to {hi})"


def _sync_rows(folder: Path) -> list[Row]:
    out: list[Row] = []
    drift = {r["estimator"]: r for r in _load(folder, "sync-drift-600s.json")}
    out.append(
        (
            "sync, 50 ppm drift, 600 s",
            "offset error vs truth, p95 (ms); baseline: the paper's held mean",
            _ms(drift["clockfilter"]["p95"]),
            _ms(drift["mean"]["p95"]),
            "sync-drift-600s.json",
        )
    )
    runs = _load(folder, "sync-180s.json")
    for scenario in ("paper-like", "heavy-tail", "bursts", "asymmetry"):
        by = {r["estimator"]: r for r in runs if r["scenario"] == scenario}
        out.append(
            (
                f"sync, {scenario}, 180 s",
                "offset error, p95 over restarts (ms); baseline: the paper's mean",
                _ms(by["clockfilter"]["restarts"]["p95"]),
                _ms(by["mean"]["restarts"]["p95"]),
                "sync-180s.json",
            )
        )
    return out


def _latency_rows(folder: Path) -> list[Row]:
    d = _load(folder, "latency-60s.json")
    fed, bare = d["fedlab_pose"], d["bare_zenoh"]
    return [
        (
            "latency, loopback, two routers",
            "pose one way, p50 / p99 (ms); baseline: bare Zenoh pub/sub",
            f"{fed['p50_ms']:.3f} / {fed['p99_ms']:.3f}",
            f"{bare['p50_ms']:.3f} / {bare['p99_ms']:.3f}",
            "latency-60s.json",
        )
    ]


def _scale_rows(folder: Path) -> list[Row]:
    out: list[Row] = []
    for name in ("scale-16-40s.json", "scale-64-128-40s.json"):
        summary = _load(folder, name)["summary"]
        for n, modes in summary.items():
            fed, bare = modes["default"], modes["bare"]
            out.append(
                (
                    f"scale, {n} agents, 4 labs",
                    "CPU per agent (mcores); baseline: bare zenoh-python agents",
                    _summary(fed["cpu_per_agent"], 1000),
                    _summary(bare["cpu_per_agent"], 1000),
                    name,
                )
            )
            out.append(
                (
                    f"scale, {n} agents, 4 labs",
                    "pose p99 (ms); loss",
                    f"{_summary(fed['p99_ms'])}; {fed['loss']['max']:g}",
                    f"{_summary(bare['p99_ms'])}; {bare['loss']['max']:g}",
                    name,
                )
            )
    big = _load(folder, "scale-256-8labs-150s.json")
    for r in big:
        out.append(
            (
                f"scale, {r['n']} agents, {r['labs']} labs",
                "CPU per agent (mcores); pose p99 (ms); poses lost",
                f"{r['cpu_per_agent'] * 1000:.2f}; {r['p99_ms']:.2f}; "
                f"{round(r['loss'] * r['samples'])} of {r['samples']}",
                "",
                "scale-256-8labs-150s.json",
            )
        )
    return out


def _memory_rows(folder: Path) -> list[Row]:
    rows = _load(folder, "memory-32-128.json")["rows"]
    out: list[Row] = []
    for n in sorted({r["n"] for r in rows}):

        def kib(mode: str, n: int = n) -> str:
            kibs = (r["kib_per_agent"] for r in rows if (r["n"], r["mode"]) == (n, mode))
            return _spread(kibs, "{:.1f}")

        out.append(
            (
                f"memory, {n} agents in one process",
                "KiB per agent added; baseline: bare zenoh-python",
                kib("default"),
                kib("bare"),
                "memory-32-128.json",
            )
        )
    return out


def _network_rows(folder: Path) -> list[Row]:
    out: list[Row] = []
    for name, link in (
        ("network-sync-estimator-60s.json", "TCP (shipped)"),
        ("network-sync-estimator-multilink-60s.json", "TCP + UDP multilink"),
    ):
        results = _load(folder, name)["results"]
        for scenario in ("loss1", "loss5", "loss20"):
            runs = [r for r in results if r["scenario"]["name"] == scenario]
            holds = ", ".join(str(r["holds"]) for r in runs)
            p99 = ", ".join(f"{r['pose_latency_ms']['p99']:.0f}" for r in runs)
            loss = round(runs[0]["scenario"]["loss"] * 100)
            out.append(
                (
                    f"network, 40 ms, {loss} % loss, {link}",
                    "safe holds per 60 s; pose p99 (ms), each run",
                    f"{holds}; {p99}",
                    "",
                    name,
                )
            )
    return out


def _generated_rows(folder: Path) -> list[Row]:
    """The generated deployment (its QUIC lab link, access control and limits), per loss."""
    name = "network-generated-loss5-60s.json"
    results = [r for r in _load(folder, name)["results"] if "error" not in r]
    out: list[Row] = []
    for loss in sorted({r["scenario"]["loss"] for r in results}):
        runs = [r for r in results if r["scenario"]["loss"] == loss]
        out.append(
            (
                f"network, 40 ms, {round(loss * 100)} % loss, generated deployment "
                f"({', '.join(sorted({_link(e) for r in runs for e in r['lab_link']}))})",
                "safe holds per 60 s; pose p99 (ms), each run",
                ", ".join(str(r["holds"]) for r in runs)
                + "; "
                + ", ".join(f"{r['pose_latency_ms']['p99']:.0f}" for r in runs),
                "",
                name,
            )
        )
    return out


def _link(endpoint: str) -> str:
    """A Zenoh endpoint's protocol and metadata: ``quic/HOST:PORT?mixed_rel=1`` is
    ``quic mixed_rel=1``."""
    scheme, _, rest = endpoint.partition("/")
    metadata = rest.partition("#")[0].partition("?")[2]
    return f"{scheme} {metadata}" if metadata else scheme


def _scenario_rows(folder: Path) -> list[Row]:
    d = _load(folder, "scenarios.json")
    out: list[Row] = []
    for f in d["formation"]:
        if f["delay_s"] < 0.2:
            continue
        on = "on" if f["latency_compensation"] else "off"
        out.append(
            (
                f"formation, {f['delay_s'] * 1000:.0f} ms, compensation {on}",
                "slot error RMS per seed (cm)",
                ", ".join(f"{e * 100:.2f}" for e in f["error_rms_m"]),
                "",
                "scenarios.json",
            )
        )
    dock = d["docking"]
    out.append(
        (
            f"docking, {dock['delay_s'] * 1000:.0f} ms",
            "seeds docked; closing speed at contact, median (cm/s)",
            f"{dock['successes']} of {dock['seeds']}; "
            + f"{statistics.median(r['contact_speed_mps'] for r in dock['runs']) * 100:.2f}",
            "",
            "scenarios.json",
        )
    )
    return out


def _ratio(stats: dict[str, float | None]) -> str:
    med, lo, hi = stats["median"], stats["min"], stats["max"]
    if med is None or lo is None or hi is None:
        return "none"
    return f"{med:.3f}" if f"{lo:.3f}" == f"{hi:.3f}" else f"{med:.3f} ({lo:.3f} to {hi:.3f})"


def _figure(values: Iterable[float | None], unit: str) -> str:
    """A no-delay figure's median, in cm for metres."""
    got = [v for v in values if v is not None]
    if not got:
        return "none"
    med = statistics.median(got)
    return f"{med * 100:.2f} cm" if unit == "m" else f"{med:.3f} {unit}"


def _transparency_rows(folder: Path) -> list[Row]:
    """Per scenario and compensation setting: the ratio at each delay; the baseline is
    the scenario's error with no delay."""
    rows = _load(folder, "scenarios.json")["transparency"]
    out: list[Row] = []
    for scenario, compensate in dict.fromkeys(
        (r["scenario"], r["latency_compensation"]) for r in rows
    ):
        mine = [
            r for r in rows if (r["scenario"], r["latency_compensation"]) == (scenario, compensate)
        ]
        first = mine[0]
        delays = "; ".join(f"{r['delay_s'] * 1000:.0f}" for r in mine)
        out.append(
            (
                f"transparency, {scenario}, compensation {'on' if compensate else 'off'}",
                f"error with {delays} ms / with none, median (min to max) of "
                f"{len(first['ratio'])} seeds; error: {first['figure']}",
                "; ".join(_ratio(r["ratio_stats"]) for r in mine),
                _figure(first["baseline"], first["unit"]),
                "scenarios.json",
            )
        )
    return out


def _merge_rows(folder: Path) -> list[Row]:
    d = _load(folder, "merge-2gib.json")
    run, fed, base = d["run"], d["merge"], d["baseline"]
    return [
        (
            f"merge, {run['mib'] / 1024:.2f} GiB run, {len(run['agents'])} agents",
            f"peak RSS (MiB; budget {d['budget_mib']:g}); MiB/s; baseline: a plain mcap read",
            f"{_summary(fed['peak_rss_mib'], fmt='{:.1f}')}"
            f"{'' if d['within_budget'] else ' (over the budget)'}; {_summary(fed['mib_per_s'])}",
            f"{_summary(base['peak_rss_mib'], fmt='{:.1f}')}; {_summary(base['mib_per_s'])}",
            "merge-2gib.json",
        )
    ]


def _formation_network_rows(folder: Path) -> list[Row]:
    """Per loss level: the formation's ratio in the testbed; the baseline is its error
    with no loss, flown in the same invocation."""
    name = "network-formation-60s.json"
    d = _load(folder, name)
    seconds = {r["seconds"] for r in d["runs"] if "seconds" in r}
    out: list[Row] = []
    for r in d["ratios"]:
        out.append(
            (
                f"transparency, formation, testbed 40 ms, {r['loss'] * 100:g} % loss",
                f"slot error with the loss / with none, same invocation, median (min to max) "
                f"of {len(r['ratio'])} repeats of {'/'.join(f'{s:g}' for s in sorted(seconds))} s",
                _ratio(r["ratio_stats"]),
                _figure(r["baseline_m"], "m"),
                name,
            )
        )
    return out


def _replay_rows(folder: Path) -> list[Row]:
    """The follower against a replayed leader over the paper's maneuver; the baseline is
    its error against the live leader, flown in the same repeat."""
    name = "replay-paper.json"
    d = _load(folder, name)
    done = [r for r in d["repeats"] if "ratio" in r]
    m, link = d["maneuver"], d["link"]
    return [
        (
            f"replay, the paper's maneuver ({m['amplitude_deg']:g} deg, {m['run_s']:g} s run), "
            f"{link['delay_ms']:g} ms link",
            f"follower's heading RMS error against the replayed leader / against the live "
            f"one, median (min to max) of {len(done)} repeats; baseline: against the live one",
            _ratio(d["summary"]["ratio"]),
            f"{d['summary']['rms_live_deg_median']:.3f} deg",
            name,
        )
    ]


_SECTIONS: tuple[Callable[[Path], list[Row]], ...] = (
    _sync_rows,
    _latency_rows,
    _scale_rows,
    _memory_rows,
    _network_rows,
    _generated_rows,
    _scenario_rows,
    _transparency_rows,
    _formation_network_rows,
    _merge_rows,
    _replay_rows,
)


def rows(folder: Path) -> list[Row]:
    """Every headline figure of the result files in ``folder``."""
    return [row for section in _SECTIONS for row in section(folder)]


def table_markdown(folder: Path, link_prefix: str = "benchmarks/") -> str:
    """The table, each file linked as ``link_prefix + name``."""
    lines = [
        "| benchmark | figure | fedlab | baseline, same run | result |",
        "|---|---|---:|---:|---|",
    ]
    for bench, figure, fed, base, name in rows(folder):
        lines.append(f"| {bench} | {figure} | {fed} | {base} | [{name}]({link_prefix}{name}) |")
    return "\n".join(lines) + "\n"

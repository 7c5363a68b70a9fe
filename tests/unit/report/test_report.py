"""``fedlab report``: summary figures recovered from synthetic recordings with known truth.

The run below is built on one host clock ``h`` (s):

- leader ``kiruna/knatte``: clock ``100 + h``; run starts at host 2 s (reference 102 s);
  the maneuver (45 deg out and back, raised cosine) spans reference 112..132 s; pose
  published every 50 ms; its true heading is its reference + 0.5 deg while running
  (and 10 deg off while armed, which the RMS must ignore).
- follower ``rome/pinocchio`` (compensated): clock ``73.58 + h (1 + 20 ppm)``, so the
  leader's clock is 26.42 s ahead; exchanges every 100 ms, 40 ms each way +-2 ms;
  its filtered estimate is the truth + 0.5 ms (+5 ms during the first 10 s); its
  guidance reference is the leader's maneuver exactly, on its own t_sim; its true
  heading trails the leader's by 4.5 s.
- follower ``rome/pinocchio-raw``: same clock; its reference is the last heading
  received, sampled 30 ms after arrival (so it trails sent by 70 ms); no /truth, its
  published heading is its reference + 1 deg.
- every leader pose arrives at both followers exactly 40 ms later.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib import image

from agents.guidance import ReferenceManeuver
from federation import cli
from federation.report import load_run, write_report
from federation.report.analysis import best_shift, heading_rms_deg, xcorr_lag
from federation.runtime.recorder import Recorder

LEADER, FOLLOWER, RAW = "kiruna/knatte", "rome/pinocchio", "rome/pinocchio-raw"
DELAY = 0.040  # s, one way
OFFSET = 26.42  # s, leader clock minus follower clock at host 0
DRIFT = 20e-6
HOST_END = 40.0  # s
START_HOST = 2.0  # s
LAG = 4.5  # s
EST_ERROR = 0.0005  # s, the filtered estimate's error after the sync phase
MANEUVER = ReferenceManeuver(start=10.0, duration=20.0, amplitude=math.radians(45.0))


def leader_clock(h: float) -> float:
    return 100.0 + h


def follower_clock(h: float) -> float:
    return 100.0 - OFFSET + h * (1.0 + DRIFT)


def follower_host(t: float) -> float:
    return (t - (100.0 - OFFSET)) / (1.0 + DRIFT)


def true_offset(t_follower: float) -> float:
    return leader_clock(follower_host(t_follower)) - t_follower


def maneuver(t_ref: float) -> tuple[float, float]:
    """Heading and rate at reference (leader clock) time."""
    return MANEUVER(t_ref - leader_clock(START_HOST))


def _pose(t: float, heading: float, omega: float = 0.0) -> dict[str, Any]:
    return {
        "t_exec": t,
        "x": 0.0,
        "y": 0.0,
        "heading": heading,
        "vx": 0.0,
        "vy": 0.0,
        "omega": omega,
    }


def _status(agent: str, role: str, t: float, h: float, peers: dict[str, Any]) -> dict[str, Any]:
    return {
        "agent": agent,
        "role": role,
        "t_exec": t,
        "host_monotonic": h,
        "peers": peers,
        "counters": {},
    }


def _exchanges(rec: Recorder, client: Any, server: Any, peer: str, truth: Any, seed: int) -> None:
    """Exchanges every 100 ms, 40 ms +-2 ms each way; estimate = truth + known error."""
    rng = np.random.default_rng(seed)
    for k in range(int(HOST_END / 0.1)):
        h1 = 0.013 + 0.1 * k
        h2 = h1 + DELAY + rng.uniform(-0.002, 0.002)
        h3 = h2 + DELAY + rng.uniform(-0.002, 0.002)
        t1, t2, t3 = client(h1), server(h2), client(h3)
        error = EST_ERROR if h3 >= 10.0 else 0.005  # large during the sync phase
        rec.record(
            "/sync/exchange",
            {
                "peer": peer,
                "t1": t1,
                "t2": t2,
                "t3": t3,
                "t2s": None,
                "offset": t2 - (t1 + t3) / 2,
                "delay": (t3 - t1) / 2,
                "estimate": truth(t3) + error,
                "host_monotonic": h3,
            },
        )


def write_run(directory: Path, with_run_json: bool = True) -> None:
    directory.mkdir(parents=True, exist_ok=True)
    hosts = np.arange(0.0, HOST_END, 0.05)
    lead = Recorder(directory / "kiruna-knatte.mcap", LEADER)
    lead.record(
        "/control",
        {
            "event": "started",
            "command": None,
            "at": None,
            "t_exec": leader_clock(START_HOST),
            "t_sim": leader_clock(START_HOST),
            "host_monotonic": START_HOST,
            "mode": "running",
            "detail": "",
        },
    )
    for h in hosts:
        t = leader_clock(h)
        heading, rate = maneuver(t)
        running = h >= START_HOST
        stamp = {"host_monotonic": h}
        lead.record("/pose/sent", stamp | _pose(t, heading, rate))
        lead.record(
            "/reference",
            stamp
            | {
                "t_exec": t,
                "t_sim": t,
                "run_time": t - leader_clock(START_HOST) if running else None,
                "heading_ref": heading,
                "rate_ref": rate,
                "mode": "running" if running else "armed",
            },
        )
        off = math.radians(0.5 if running else 10.0)
        lead.record("/truth", stamp | _pose(t, heading + off, rate))
    for h in np.arange(0.0, HOST_END, 0.5):
        lead.record("/status", _status(LEADER, "leader", leader_clock(h), h, {}))
    _exchanges(
        lead,
        leader_clock,
        follower_clock,
        FOLLOWER,
        lambda t: follower_clock(t - 100.0) - t,
        seed=2,
    )
    lead.close()

    for name, raw in ((FOLLOWER, False), (RAW, True)):
        rec = Recorder(directory / f"{name.replace('/', '-')}.mcap", name)
        for h in hosts:  # every leader pose arrives 40 ms later
            t_sent = leader_clock(h)
            heading, rate = maneuver(t_sent)
            rec.record(
                "/pose/received",
                {
                    "agent": LEADER,
                    "t": t_sent,
                    "t_recv": follower_clock(h + DELAY),
                    "host_monotonic": h + DELAY,
                    **{k: v for k, v in _pose(0, heading, rate).items() if k != "t_exec"},
                },
            )
        for h in hosts + 0.02:  # the follower's own pose ticks
            t = follower_clock(h)
            t_sim = t + true_offset(t) + EST_ERROR
            # raw: the last heading received, sent 30 ms + DELAY ago; compensated: exact
            heading_ref = maneuver(leader_clock(h - 0.03 - DELAY) if raw else t_sim)[0]
            running = h >= START_HOST
            stamp = {"host_monotonic": h}
            rec.record(
                "/reference",
                stamp
                | {
                    "t_exec": t,
                    "t_sim": t_sim,
                    "run_time": None,
                    "heading_ref": heading_ref,
                    "rate_ref": 0.0,
                    "mode": "running" if running else "armed",
                },
            )
            if raw:
                rec.record("/pose/sent", stamp | _pose(t, heading_ref + math.radians(1.0)))
            else:
                lagged = maneuver(leader_clock(h) - LAG)[0]
                rec.record("/pose/sent", stamp | _pose(t, lagged))
                rec.record("/truth", stamp | _pose(t, lagged))
        peers = {LEADER: {"rejected": 3}}
        for h in np.arange(0.0, HOST_END, 0.5):
            rec.record("/status", _status(name, "follower", follower_clock(h), h, peers))
        _exchanges(rec, follower_clock, leader_clock, LEADER, true_offset, seed=1)
        rec.close()

    if with_run_json:
        agents = {
            LEADER: {
                "role": "leader",
                "platform": "knatte",
                "clock_offset": 0.0,
                "clock_drift_ppm": 0.0,
            },
            FOLLOWER: {
                "role": "follower",
                "follow": LEADER,
                "platform": "pinocchio",
                "latency_compensation": True,
                "clock_offset": OFFSET,
                "clock_drift_ppm": 20.0,
            },
            RAW: {
                "role": "follower",
                "follow": LEADER,
                "platform": "pinocchio",
                "latency_compensation": False,
                "clock_offset": OFFSET,
                "clock_drift_ppm": 20.0,
            },
        }
        run = {
            "leader": LEADER,
            "agents": agents,
            "link": {"delay_ms": 40.0, "jitter_ms": 2.0},
            "duration_s": HOST_END,
            "command": "fedlab demo --duration 40",
        }
        (directory / "run.json").write_text(json.dumps(run))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("run")
    write_run(directory)
    return directory


@pytest.fixture(scope="module")
def written(run_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    out = tmp_path_factory.mktemp("out")
    return write_report(run_dir, out), out


def _sync(summary: dict[str, Any], client: str) -> dict[str, Any]:
    (pair,) = [s for s in summary["sync"] if s["client"] == client]
    return pair


def _follower(summary: dict[str, Any], name: str) -> dict[str, Any]:
    (f,) = [f for f in summary["followers"] if f["follower"] == name]
    return f


# -- pure pieces ----------------------------------------------------------------------------
def test_best_shift_finds_a_known_delay_and_refuses_the_edge() -> None:
    t = np.arange(0.0, 20.0, 0.05)
    x = np.sin(0.5 * t)
    assert best_shift(t + 0.0371, x, t, x) == pytest.approx(0.0371, abs=2e-4)
    assert best_shift(t - 0.012, x, t, x) == pytest.approx(-0.012, abs=2e-4)
    assert best_shift(t + 0.8, x, t, x) is None  # beyond +-0.5 s


def test_xcorr_lag_finds_a_lag_and_needs_motion() -> None:
    t = np.arange(0.0, 60.0, 0.05)
    ref = np.exp(-(((t - 20.0) / 4.0) ** 2))
    follower = np.exp(-(((t - 24.3) / 4.0) ** 2))
    assert xcorr_lag(t, follower, t, ref) == pytest.approx(4.3, abs=0.01)
    assert xcorr_lag(t, np.zeros_like(t), t, ref) is None


def test_heading_rms_uses_only_running_samples() -> None:
    reference = [
        {"t_exec": float(t), "heading_ref": 0.0, "mode": "running" if t >= 5 else "armed"}
        for t in range(10)
    ]
    heading = [
        {"t_exec": float(t), "heading": math.radians(2.0 if t >= 5 else 30.0)} for t in range(10)
    ]
    assert heading_rms_deg(heading, reference) == pytest.approx(2.0)


# -- the synthetic run ----------------------------------------------------------------------
def test_sync_figures_recover_the_known_delay_offset_and_estimate_error(
    written: tuple[dict[str, Any], Path],
) -> None:
    summary, _ = written
    s = _sync(summary, FOLLOWER)
    assert s["peer"] == LEADER
    assert s["delay_median_s"] == pytest.approx(DELAY, abs=1e-3)
    assert 0.0005 < s["delay_std_s"] < 0.002  # two uniform +-2 ms legs, halved
    assert s["offset_median_s"] == pytest.approx(OFFSET, abs=1e-3)
    assert s["true_offset_median_s"] == pytest.approx(true_offset(follower_clock(20.0)), abs=1e-4)
    # The 5 ms error of the sync phase is left out; after it the error is 0.5 ms exactly.
    assert s["estimate_error_median_abs_s"] == pytest.approx(EST_ERROR, abs=1e-6)
    assert s["estimate_error_max_abs_s"] == pytest.approx(EST_ERROR, abs=1e-6)
    assert s["emulated_delay_s"] == pytest.approx(0.040)
    assert s["delay_median_minus_emulated_s"] == pytest.approx(s["delay_median_s"] - 0.040)
    assert s["exchanges_count"] == 400
    assert s["rejected_count"] == 3
    # The leader syncs with the follower too: the offset is the other way round.
    back = _sync(summary, LEADER)
    assert back["offset_median_s"] == pytest.approx(-OFFSET, abs=2e-3)


def test_separation_is_zero_when_compensated_and_the_delay_when_raw(
    written: tuple[dict[str, Any], Path],
) -> None:
    summary, _ = written
    comp, raw = _follower(summary, FOLLOWER), _follower(summary, RAW)
    assert comp["latency_compensation"] is True and raw["latency_compensation"] is False
    assert comp["reference_separation_s"] == pytest.approx(0.0, abs=5e-4)
    # Held 30 ms after arrival, on a t_sim 0.5 ms ahead of the truth.
    assert raw["reference_separation_s"] == pytest.approx(DELAY + 0.030 + EST_ERROR, abs=2e-4)
    for f in (comp, raw):
        assert f["received_separation_s"] == pytest.approx(DELAY, abs=5e-4)
        assert f["received_time_source"] == "truth"
        assert f["pose_age_median_s"] == pytest.approx(DELAY, abs=1e-6)
        assert f["pose_received_count"] == 800
        assert f["maneuver_s"] == pytest.approx([10.0, 30.0], abs=0.06)


def test_lag_and_heading_rms(written: tuple[dict[str, Any], Path]) -> None:
    summary, _ = written
    assert _follower(summary, FOLLOWER)["lag_s"] == pytest.approx(LAG, abs=0.01)
    # The raw follower's published heading is its reference + 1 deg: 70 ms behind the leader.
    assert _follower(summary, RAW)["lag_s"] == pytest.approx(0.07, abs=0.01)
    agents = summary["agents"]
    assert agents[LEADER]["heading_rms_error_deg"] == pytest.approx(0.5, abs=1e-9)
    assert agents[LEADER]["heading_source"] == "truth"
    assert agents[RAW]["heading_rms_error_deg"] == pytest.approx(1.0, abs=1e-9)
    assert agents[RAW]["heading_source"] == "estimate"
    # The compensated follower: truth lags its reference by 4.5 s (+ the 0.5 ms estimate error).
    hosts = np.arange(START_HOST, HOST_END, 0.05) + 0.02
    hosts = hosts[hosts >= START_HOST]
    err = [
        maneuver(leader_clock(h) - LAG)[0] - maneuver(leader_clock(h) + EST_ERROR)[0] for h in hosts
    ]
    expected = math.degrees(math.sqrt(float(np.mean(np.square(err)))))
    assert agents[FOLLOWER]["heading_rms_error_deg"] == pytest.approx(expected, rel=1e-6)
    assert expected > 5.0


UNITS = ("_s", "_deg", "_count", "_ms", "_range")


def _numbers_without_units(value: Any, key: str = "") -> list[str]:
    """Keys of numbers whose name (or whose parent's, for a dict of them) has no unit."""
    units = UNITS
    if isinstance(value, dict):
        return [
            k
            for name, v in value.items()
            for k in _numbers_without_units(v, key if key.endswith(units) else name)
        ]
    if isinstance(value, list):
        return [k for v in value for k in _numbers_without_units(v, key)]
    is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
    return [key] if is_number and not key.endswith(units) else []


def test_summary_json_names_a_unit_in_every_numeric_key(
    written: tuple[dict[str, Any], Path],
) -> None:
    summary, out = written
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["sync"] == summary["sync"]
    assert _numbers_without_units(on_disk) == []
    assert on_disk["link"] == {"emulated_delay_s": 0.040, "emulated_jitter_s": 0.002}


def test_figures_are_real_pngs_and_the_report_shows_them(
    written: tuple[dict[str, Any], Path],
) -> None:
    summary, out = written
    names = summary["figures"]
    assert set(names) >= {"heading", "sent_vs_received", f"sync {FOLLOWER} {LEADER}"}
    md = (out / "report.md").read_text()
    for name in names.values():
        path = out / name
        assert path.stat().st_size > 20_000
        pixels = image.imread(path)
        assert pixels.shape[1] == 1500  # 10 in at 150 dpi
        assert pixels.shape[0] >= 750
        assert pixels[..., :3].std() > 0.05  # not a blank canvas
        assert f"]({name})" in md
    assert "| figure | pair or agent | this run | paper |" in md
    lines = md.splitlines()
    first = lines.index("| figure | pair or agent | this run | paper |")
    rows = lines[first + 2 : lines.index("", first)]
    assert len(rows) > 20
    assert all(row.replace("\\|", "").count("|") == 5 for row in rows)  # 4 cells each
    assert "60–100" in md and "4–5" in md  # the paper's separation and lag
    assert "40.0 ms one-way delay" in md  # what was emulated
    assert "the source paper (docs/paper.md)" in md and "NOTES.md" not in md


# -- missing pieces and the command line ---------------------------------------------------
def test_missing_leader_and_run_json_are_reported_not_fatal(tmp_path: Path) -> None:
    write_run(tmp_path, with_run_json=False)
    (tmp_path / "kiruna-knatte.mcap").unlink()
    summary = write_report(tmp_path)
    s = _sync(summary, FOLLOWER)
    assert s["delay_median_s"] == pytest.approx(DELAY, abs=1e-3)
    assert "estimate_error_median_abs_s" not in s  # no truth without the leader's clock
    assert summary["followers"] == []
    notes = " ".join(summary["notes"])
    assert "no run.json" in notes
    assert "kiruna/knatte, which has no recording" in notes
    assert summary["agents"][FOLLOWER]["role"] == "follower"  # from its recorded status
    assert (tmp_path / "report.md").exists() and (tmp_path / "summary.json").exists()


OLD_EXPERIMENT = {
    "name": "paper", "duration": 40.0, "start_delay": 0.5,
    "participants": [
        {"agent": LEADER, "role": "leader"},
        {"agent": FOLLOWER, "role": "follower", "follow": LEADER},
    ],
}  # fmt: skip
"""Recorded when a start could come 0.5 s after its command (now at least 1 s): a rule
for launching runs, not for reading them. Its report had failed."""


# One report each (a report draws every figure: one test of three took 34 s at nice 10).
@pytest.mark.parametrize("experiment", ["old", "does not load", "cut short"])
def test_an_old_or_broken_experiment_json_costs_the_report_nothing_else(
    tmp_path: Path, experiment: str
) -> None:
    write_run(tmp_path, with_run_json=False)
    text = {
        "old": json.dumps(OLD_EXPERIMENT),
        "does not load": json.dumps({**OLD_EXPERIMENT, "duration": -1}),
        "cut short": json.dumps(OLD_EXPERIMENT)[:20],  # a power cut
    }[experiment]
    (tmp_path / "experiment.json").write_text(text)
    summary = write_report(tmp_path)
    notes = " ".join(summary["notes"])
    if experiment == "old":
        assert summary["followers"] and "does not load" not in notes
    elif experiment == "does not load":
        # The rest of the report stands, and says why.
        assert "experiment.json: field 'duration'" in notes and "no scenario figures" in notes
        assert "no run.json" in notes  # the run's own notes are kept beside it
        assert summary["followers"] and (tmp_path / "report.md").exists()
    else:  # a note too, not a crash
        assert "experiment.json: not a JSON file" in notes and "no scenario figures" in notes


def test_damaged_recordings_are_recovered_or_skipped_with_a_note(
    run_dir: Path, tmp_path: Path
) -> None:
    shutil.copytree(run_dir, tmp_path, dirs_exist_ok=True)
    # Bytes after the end: the summary cannot be found, every message still can.
    damaged = tmp_path / "rome-pinocchio-raw.mcap"
    damaged.write_bytes(damaged.read_bytes() + b"not mcap")
    # Cut in the middle of its only chunk: nothing to recover.
    truncated = tmp_path / "rome-pinocchio.mcap"
    truncated.write_bytes(truncated.read_bytes()[:5000])
    run = load_run(tmp_path)
    assert set(run.agents) == {LEADER, RAW}
    assert len(run.agents[RAW].channel("/status")) == 80
    notes = " ".join(run.notes)
    assert "rome-pinocchio-raw.mcap: damaged or unfinished recording" in notes
    assert "rome-pinocchio.mcap: unreadable" in notes
    assert "rome/pinocchio is in run.json but has no recording" in notes


def test_cli_writes_into_out_and_prints_the_table(
    run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / ("a-folder-with-a-long-name-" * 4)  # wider than the 80-column console
    assert cli.main(["report", str(run_dir), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "delay median (ms)" in printed and "40.0" in printed
    assert f"wrote to {out}: summary.json" in printed  # the path whole, on one line
    assert (out / "summary.json").exists()
    assert not (run_dir / "summary.json").exists()  # --out kept the run directory clean


@pytest.mark.parametrize("make", [lambda p: p, lambda p: p / "missing"])
def test_cli_without_recordings_fails_naming_the_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], make: Any
) -> None:
    directory = make(tmp_path)
    assert cli.main(["report", str(directory)]) == 2
    err = capsys.readouterr().err
    assert str(directory) in err and "error" in err


def test_help_has_an_example(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["report", "--help"])
    out = capsys.readouterr().out
    assert "Examples:" in out and "fedlab report runs/" in out and "--out DIR" in out
    assert "merged.mcap" in out and "--source" in out

"""Rejoining a run under way, with real processes over two routers and the link
emulator (40 ms one way): a simulated follower killed (SIGKILL) at run time ~6 s of a
20 s run and started again rejoins on its own (its platform's default, ``auto``) within
5 s of its start, at the present run time, and flies the run to its end with the
leader, on the same run id and end instant. ``fedlab collect`` gathers both its
segments; ``fedlab report`` shows one run, the follower's two segments and the gap
between them, and the run completed by the leader."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from lifecycle import as_json, fedlab, participants, write_experiment
from loopback import FOLLOWER, LEADER, Labs

pytestmark = pytest.mark.integration

LOCKED = 25.0  # s: the agents start (slow on a busy host), then the estimate locks 2 s in
RUN = 14.0  # s of run time
KILL_AT = 4.0  # s of run time at which the follower is killed
REJOIN_WITHIN = 5.0  # s after its session is up


def _rejoined(line: dict[str, object]) -> bool:
    transition = line.get("transition")
    return isinstance(transition, dict) and transition.get("event") == "rejoined"


def test_a_killed_follower_started_again_rejoins_and_flies_to_the_end(
    labs: Labs, tmp_path: Path
) -> None:
    pair = labs.pair(link=["--delay-ms", "40"])
    experiment = write_experiment(tmp_path / "exp.toml", RUN)
    # The restarted follower joins once its estimate of the reference clock locks, a
    # sync window after its first exchange: 1 s here (the paper's 10 s by default).
    agents = participants(labs, pair, experiment, "--sync-window", "1")
    leader, follower = agents[LEADER], agents[FOLLOWER]
    follower.until(
        lambda s: (s.get("ready") or {}).get("reference_locked") and s["mode"] == "waiting",
        timeout=LOCKED,
        what="locked, waiting",
    )
    started, _ = fedlab(
        "ctl", "start", "--experiment", str(experiment), "--run-id", "rejoin",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    line = follower.until(
        lambda s: (s.get("run_time") or 0.0) >= KILL_AT, timeout=15, what=f"run time {KILL_AT} s"
    )
    follower.kill()
    killed_at = line["run_time"]
    end_at = line["start_at"] + RUN  # the run's end instant on reference time

    begun = time.monotonic()
    follower.start()
    # Timed from its first status line, when its session is up: the interpreter's own
    # start before it (1.5 s idle, 4 s on cores shared with parallel tests) is not
    # rejoining's.
    up = follower.until(lambda s: s["host_monotonic"] > begun, REJOIN_WITHIN + 10, "up again")
    joined = follower.until(_rejoined, timeout=REJOIN_WITHIN + 5, what="rejoined")
    rejoin_s = joined["host_monotonic"] - up["host_monotonic"]
    started_s = up["host_monotonic"] - begun
    for line in follower.log().splitlines():  # when it came up, synced and rejoined
        if "rejoin" in line or " up in federation" in line:
            print(line)
    transition = joined["transition"]
    gap = transition["run_time"] - killed_at
    print(
        f"killed at run time {killed_at:.2f} s; up {started_s:.2f} s after its start, "
        f"rejoined {rejoin_s:.2f} s after it was up, "
        f"at run time {transition['run_time']:.2f} s (gap {gap:.2f} s)"
    )
    assert rejoin_s <= REJOIN_WITHIN, rejoin_s
    assert joined["run_id"] == "rejoin" and joined["mode"] in ("running", "done")
    assert killed_at < transition["run_time"] < RUN
    assert joined["start_at"] == pytest.approx(end_at - RUN, abs=1e-6)  # the same run

    done = follower.until(lambda s: s["mode"] == "done", timeout=RUN, what="done")
    assert done["run_id"] == "rejoin" and done["run_time"] == pytest.approx(RUN)
    assert done["transition"]["event"] == "done"
    assert done["transition"]["at"] == pytest.approx(end_at, abs=1e-6)  # the others' end
    led = leader.until(lambda s: s["mode"] == "done", timeout=5, what="the leader done")
    assert led["transition"]["at"] == pytest.approx(end_at, abs=1e-6)
    assert led["hold"] == "done" and done["hold"] == "done"
    rejoined_at = transition["run_time"]

    out = tmp_path / "collected"
    collected, _ = fedlab(
        "collect", "rejoin", "--out", str(out), "--experiment", str(experiment), "--json",
        "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert collected.returncode == 0, collected.stdout + collected.stderr
    got = as_json(collected)
    stem = FOLLOWER.replace("/", "-")
    assert {f"{stem}.mcap", f"{stem}.seg2.mcap", f"{stem}.seg2.jsonl"} <= set(
        got["files"][FOLLOWER]
    ), got["files"]
    parts = got["participants"]
    print(f"collect: {json.dumps(parts)}")
    assert parts[LEADER]["complete"] is True and parts[LEADER]["gaps_s"] == []
    follower_part = parts[FOLLOWER]
    assert follower_part["ended"] == "done" and follower_part["complete"] is False
    assert follower_part["reached_s"] == pytest.approx(RUN)
    (first, second) = follower_part["segments_s"]
    # What the kill left of the first segment: its records up to the last chunk written.
    assert first[0] == pytest.approx(0.0) and 0.0 < first[1] <= killed_at + 0.5
    assert second == [pytest.approx(rejoined_at, abs=1e-6), pytest.approx(RUN)]
    assert follower_part["gaps_s"] == [[first[1], second[0]]]

    report, _ = fedlab("report", str(out), "--out", str(out / "report"))
    assert report.returncode == 0, report.stdout + report.stderr
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert summary["run"]["participants"] == parts
    text = (out / "report" / "report.md").read_text()
    assert f"| {FOLLOWER} | {RUN:.1f} | no | done: its run time reached the duration | 2 |" in text
    assert f"| {first[1]:.1f} to {second[0]:.1f} |" in text
    assert f"| {LEADER} | {RUN:.1f} | yes |" in text
    print(f"segments {follower_part['segments_s']}, gap {follower_part['gaps_s']}")

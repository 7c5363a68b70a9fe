"""A real platform's agent restarted mid-run, with real processes over two routers and
the link emulator (40 ms one way): a serial follower (an emulated device on a
pseudo-terminal, the pinocchio preset) killed (SIGKILL) mid-run and started again
stays held, waiting for an operator's admit (its platform's default rejoin policy,
``operator``), its device seeing no valve open, and says so in its status and in
``fedlab ctl status``; ``fedlab ctl admit`` lets it join the run, its thrusters fire,
and it flies to the run's end with the leader."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from loopback import FOLLOWER, LEADER, Labs

from federation.fleet.launch import Fleet, wait_for

pytestmark = pytest.mark.integration

RUN = 22.0  # s of run time: 21 s after the kill for a restart on loaded cores, sync, admit
KILL_AT = 1.0  # s of run time: the run is under way
HELD_FOR = 2.5  # s it is watched, held, once ready to join


def _valves(events: Path) -> list[dict[str, Any]]:
    records = [json.loads(line) for line in events.read_text().splitlines() if line.strip()]
    return [r for r in records if r["event"] == "valves"]


def _fedlab(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "federation", *args],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )  # fmt: skip


def test_a_serial_follower_restarted_mid_run_stays_held_until_admitted(
    labs: Labs, fleet: Fleet, tmp_path: Path
) -> None:
    tty, events = tmp_path / "pinocchio-tty", tmp_path / "device.jsonl"
    fleet.start(
        "device",
        ["emulate-device", "--link", str(tty), "--record", str(events), "--platform",
         "pinocchio", "--duration", "120"],
    )  # fmt: skip
    pair = labs.pair(link=["--delay-ms", "40"])  # while the emulator starts
    assert wait_for(tty.exists, timeout=10), "the emulator never opened its pty"
    leader = labs.leader(pair.kiruna, "--platform", "knatte", "--wait-start", "--sync-window", "1")
    serial = ["--platform", f"serial:{tty}", "--platform-preset", "pinocchio"]
    follower = labs.follower(pair.rome, *serial, "--wait-start", "--sync-window", "1")
    follower.until(
        lambda s: (s.get("ready") or {}).get("reference_locked") and s["mode"] == "waiting",
        timeout=25, what="locked, waiting",
    )  # fmt: skip
    started = _fedlab(
        "ctl", "start", "--reference", LEADER, "--in", "2", "--duration", str(RUN),
        "--run-id", "serial-rejoin", "--force", "-e", pair.kiruna.endpoint,
    )  # fmt: skip
    assert started.returncode == 0, started.stdout + started.stderr
    follower.until(lambda s: (s.get("run_time") or 0.0) >= KILL_AT, 15, f"run time {KILL_AT} s")
    follower.kill()
    time.sleep(0.5)  # the device's heartbeat failsafe closes what was open
    before = len(_valves(events))

    begun = time.monotonic()
    follower.start()
    waiting = follower.until(
        lambda s: s.get("admit_run") == "serial-rejoin", 20, "waiting for an admit"
    )
    assert waiting["mode"] == "waiting" and waiting["hold"] == "waiting"
    assert waiting["rejoin"] == f"waiting for an operator's admit (fedlab ctl admit {FOLLOWER})"
    table = _fedlab("ctl", "status", "--json", "-e", pair.rome.endpoint)
    rows = {r["agent"]: r for r in json.loads(table.stdout)["agents"]}
    assert rows[FOLLOWER]["admit_run"] == "serial-rejoin", rows
    deadline = time.monotonic() + HELD_FOR
    while time.monotonic() < deadline:  # a run under way, and it stays held
        line = follower.latest()
        assert line["mode"] == "waiting" and line["hold"] == "waiting", line
        time.sleep(0.2)
    opened = [v for v in _valves(events)[before:] if v["mask"]]
    assert not opened, f"a valve opened without an admit: {opened[:3]}"
    held_s = time.monotonic() - begun

    admitted = _fedlab("ctl", "admit", FOLLOWER, "--json", "-e", pair.rome.endpoint)
    assert admitted.returncode == 0, admitted.stdout + admitted.stderr
    result = json.loads(admitted.stdout)
    joined_at = result["joined"][FOLLOWER]
    print(
        f"held {held_s:.1f} s after its restart, waiting for the admit; admitted: rejoined "
        f"{result['elapsed_s']:.2f} s after ctl admit, at run time {joined_at:.2f} s"
    )
    assert KILL_AT < joined_at < RUN
    done = follower.until(lambda s: s["mode"] == "done", RUN + 5, "done")
    assert done["run_id"] == "serial-rejoin" and done["run_time"] == pytest.approx(RUN)
    assert any(v["mask"] for v in _valves(events)[before:]), "its thrusters never fired"
    assert leader.until(lambda s: s["mode"] == "done", 5, "the leader done")["run_time"] == (
        pytest.approx(RUN)
    )

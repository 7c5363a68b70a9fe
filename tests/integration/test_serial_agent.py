"""A real agent flying an emulated device over a pseudo-terminal: ``--platform serial:PORT``.

The serial platform flies the simulated platform's GNC chain (agents/gnc.py), and the
emulated device is the simulated platform's plant (agents/simulated.py) behind the
serial protocol: with one preset on both sides, a real-platform follower tracks a
leader as well as a simulated follower of the same preset does.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from federation.core.angles import wrap_angles
from federation.fleet.launch import Fleet, wait_for
from federation.report.status import last_status, read_status
from federation.runtime.recorder import read_messages

pytestmark = pytest.mark.integration


def _device_events(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_agent_flies_the_maneuver_through_a_serial_device(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    tty, events = tmp_path / "knatte-tty", tmp_path / "device.jsonl"
    fleet.start(
        "device",
        ["emulate-device", "--link", str(tty), "--record", str(events), "--seed", "1"],
    )
    assert wait_for(tty.exists, timeout=10), "the emulator never opened its pty"
    ep = endpoint()
    fleet.start("router", ["router", "--lab", "kiruna", "-l", ep])
    status = tmp_path / "knatte.jsonl"
    # A short maneuver: 1 s still, 20 degrees out and back in 8 s.
    config = tmp_path / "agent.toml"
    config.write_text(
        'lab = "kiruna"\nname = "knatte"\nrole = "leader"\n'
        f'platform = "serial:{tty}"\nstatus_period = 0.5\nstatus_json = "{status}"\n'
        "[maneuver]\nstill = 1.0\nduration = 8.0\namplitude_deg = 20.0\n"
    )
    fleet.start("agent", ["agent", "--agent-config", str(config), "-e", ep])

    def turned() -> bool:
        line = last_status(status)
        return line is not None and math.degrees(line["pose"][2]) > 10.0

    assert wait_for(turned, timeout=20), last_status(status)
    lines = read_status(status)
    assert lines[-1]["platform"] == f"serial:{tty}"
    assert lines[-1]["loop"]["rate_hz"] == 100.0
    # Stopping the agent leaves the device with every valve closed.
    assert fleet.stop("agent") == 0
    fleet.stop("device")
    records = [json.loads(line) for line in events.read_text().splitlines()]
    valve_commands = [r for r in records if r["event"] == "valves"]
    assert any(r["mask"] for r in valve_commands), "the thrusters never fired"
    assert valve_commands[-1]["mask"] == 0, valve_commands[-1]


STILL, DURATION, AMPLITUDE = 2.0, 20.0, 45.0  # the paper's maneuver, shortened: s, s, deg


def _heading_rms(recording: Path, start: float, end: float) -> tuple[float, int]:
    """RMS (deg) of the published heading (the navigation estimate) minus the heading
    reference the agent flew, over run times ``start`` to ``end`` (the leader's clock);
    and the number of samples."""
    messages = read_messages(recording, ["/pose/sent", "/reference"])
    sent, reference = messages["/pose/sent"], messages["/reference"]
    assert len(sent) == len(reference) > 0  # recorded in pairs, one pair per published pose
    error = [
        p["heading"] - r["heading_ref"]
        for p, r in zip(sent, reference, strict=True)
        if r["run_time"] is not None and start <= r["run_time"] <= end
    ]
    assert error, f"{recording.name}: no sample between run times {start} and {end} s"
    wrapped = wrap_angles(np.array(error))
    return math.degrees(float(np.sqrt(np.mean(wrapped**2)))), len(error)


def test_a_serial_follower_tracks_as_well_as_a_simulated_one(
    fleet: Fleet, endpoint: Callable[[], str], tmp_path: Path
) -> None:
    """A kinematic leader flies the paper's maneuver (shortened); a simulated PINOCCHIO
    and a real-platform PINOCCHIO (emulated device, serial port, the pinocchio GNC
    preset) follow it. Their heading RMS errors against the references they flew agree."""
    ep = endpoint()
    fleet.start("router", ["router", "--lab", "lab", "-l", ep])
    tty, device_events = tmp_path / "pinocchio-tty", tmp_path / "device.jsonl"
    fleet.start(
        "device",
        ["emulate-device", "--platform", "pinocchio", "--link", str(tty),
         "--record", str(device_events), "--duration", "120"],
    )  # fmt: skip
    assert wait_for(tty.exists, timeout=10), "the emulator never opened its pty"
    common = ["--role", "follower", "--follow", "kiruna/knatte", "--status-period", "0.5",
              "-e", ep]  # fmt: skip
    followers = {
        "simulated": ["--platform", "pinocchio"],
        "serial": ["--platform", f"serial:{tty}", "--platform-preset", "pinocchio"],
    }
    for name, platform in followers.items():
        fleet.start(
            f"agent-{name}",
            ["agent", "--lab", "rome", "--name", name, *platform, *common,
             "--status-json", str(tmp_path / f"{name}.jsonl"),
             "--record", str(tmp_path / f"{name}.mcap")],
        )  # fmt: skip
    for name in followers:
        path = tmp_path / f"{name}.jsonl"
        assert wait_for(lambda p=path: last_status(p) is not None, timeout=20), name
    # The leader last: its maneuver starts STILL seconds after it does, followers tracking.
    leader_status = tmp_path / "leader.jsonl"
    fleet.start(
        "agent-leader",
        ["agent", "--lab", "kiruna", "--name", "knatte", "--role", "leader",
         "--status-period", "0.5", "--status-json", str(leader_status), "-e", ep,
         "--agent-config", str(_maneuver_file(tmp_path))],
    )  # fmt: skip
    end = STILL + DURATION + 2.0

    def done() -> bool:
        line = last_status(leader_status)
        return line is not None and (line.get("run_time") or 0.0) > end + 0.5

    assert wait_for(done, timeout=end + 40), last_status(leader_status)
    serial_status = last_status(tmp_path / "serial.jsonl")
    assert serial_status is not None and serial_status["platform"] == f"serial:{tty}"
    assert serial_status["loop"]["rate_hz"] == 100.0
    for name in ("serial", "simulated", "leader"):
        assert fleet.stop(f"agent-{name}") == 0, name
    rms = {name: _heading_rms(tmp_path / f"{name}.mcap", STILL - 1.0, end) for name in followers}
    print(
        f"\n[serial follower] paper maneuver shortened ({STILL:.0f} s still, {AMPLITUDE:.0f} deg "
        f"out and back in {DURATION:.0f} s), PINOCCHIO following a kinematic leader: heading "
        f"RMS error vs its reference: simulated {rms['simulated'][0]:.3f} deg "
        f"({rms['simulated'][1]} samples), serial (emulated device, pinocchio GNC) "
        f"{rms['serial'][0]:.3f} deg ({rms['serial'][1]} samples); "
        f"ratio {rms['serial'][0] / rms['simulated'][0]:.2f} (bound 1.5)"
    )
    assert rms["serial"][0] <= 1.5 * rms["simulated"][0]
    assert rms["simulated"][0] < 2.0  # both followed: degrees, not tens of degrees
    # Stopping the serial agent left the device with every valve closed.
    fleet.stop("device")
    valves = [e for e in _device_events(device_events) if e["event"] == "valves"]
    assert any(e["mask"] for e in valves), "the serial follower's thrusters never fired"
    assert valves[-1]["mask"] == 0, valves[-1]


def _maneuver_file(tmp_path: Path) -> Path:
    path = tmp_path / "leader.toml"
    path.write_text(
        'lab = "kiruna"\nname = "knatte"\nrole = "leader"\n'
        f"[maneuver]\nstill = {STILL}\nduration = {DURATION}\namplitude_deg = {AMPLITUDE}\n"
    )
    return path

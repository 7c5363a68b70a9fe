"""A real agent flying an emulated device over a pseudo-terminal: ``--platform serial:PORT``."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest

from federation.fleet.launch import Fleet, wait_for
from federation.report.status import last_status, read_status

pytestmark = pytest.mark.integration


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

"""The serial platform (agents/serial/platform.py) and ``fedlab emulate-device``.

Two layers: ``SerialPlatform`` against a scripted device on a pseudo-terminal this
test owns (exact counters, the frames it sends, a vanished port); and ``fedlab
emulate-device`` as a process with the platform closing the heading loop, through the
GNC chain, over its pseudo-terminal. The emulator's device without I/O is tested in
test_serial_emulator.py. Every loop is bounded and every process is stopped by pid
(the ``fleet`` fixture).
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from agents.dynamics import PAIRS
from agents.gnc import GncChain
from agents.platform import Platform, make_platform
from agents.serial.platform import CLOSED, PlatformError, SerialPlatform
from agents.serial.protocol import (
    FLAG_FAILSAFE,
    HOST_TO_DEVICE,
    DevicePose,
    FrameDecoder,
    Heartbeat,
    Imu,
    Message,
    Status,
    Valves,
    encode,
    encode_heartbeat,
    encode_imu,
    encode_pose,
    encode_status,
    encode_valves,
)
from agents.simulated import SimulatedPlatform
from federation import cli
from federation.cli import emulate_device
from federation.cli.common import Formatter
from federation.core.wire import Pose
from federation.fleet.launch import Fleet, wait_for
from schemas.platform import load_platform

EMULATOR = [sys.executable, "-m", "federation", "emulate-device"]
KNATTE = load_platform("knatte")
# The chain of knatte taking a first fix alone: for the tests of the serial link, each
# starting from one POSE (the default's agreeing ones with a known velocity: test_gnc.py,
# and below).
ONE_FIX = KNATTE.model_copy(
    update={
        "navigation": KNATTE.navigation.model_copy(
            update={"fixes_to_start": 1, "start_velocity_sigma": 1.0}
        )
    }
)
ALPHA = KNATTE.pair_torque / KNATTE.inertia  # rad/s^2 of a torque couple: 0.4
POSITIVE_TORQUE = tuple(i in PAIRS["+torque"] for i in range(8))  # valves 1, 2
NEGATIVE_TORQUE = tuple(i in PAIRS["-torque"] for i in range(8))  # valves 0, 3
AHEAD = 1.0  # rad: a reference this far from a platform at rest saturates +torque
WRITE_TIMEOUT = 1.0
"""s a write to the pty may take (the platform's default: 5 ms). A test host busy with
parallel workers can deschedule this process for longer mid-write, and the platform
then, as it must, treats the write as cut off and sends all-closed again: these tests'
frames assume whole writes; the tests of cut-off writes make theirs cut off."""


def main(args: list[str]) -> int:
    """``fedlab emulate-device ARGS`` in this process."""
    return cli.main(["emulate-device", *args])


# -- SerialPlatform against a scripted device on a pty this test owns ------------
class Pty:
    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.decoder = FrameDecoder(HOST_TO_DEVICE)

    def send(self, data: bytes) -> None:
        os.write(self.master, data)
        time.sleep(0.02)  # let the line deliver it

    def received(self) -> list[Message]:
        """What the host sent, decoded."""
        time.sleep(0.02)
        data = b""
        for _ in range(100):
            try:
                chunk = os.read(self.master, 4096)
            except BlockingIOError:
                break
            data += chunk
        return self.decoder.feed(data)

    def close_master(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1

    def close(self) -> None:
        self.close_master()
        os.close(self.slave)


@pytest.fixture
def pty_dev() -> Iterator[Pty]:
    p = Pty()
    try:
        yield p
    finally:
        p.close()


def _valves_of(messages: list[Message]) -> list[int]:
    return [m.mask for m in messages if isinstance(m, Valves)]


def test_no_valve_opens_before_the_first_pose(pty_dev: Pty) -> None:
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        assert plat.step(0.0, AHEAD, 0.0) == Pose()  # the filter's prior: nothing known
        sent = pty_dev.received()
        assert sent == [Valves(0, 0), Heartbeat(0, 0.0)]
        assert plat.valves == CLOSED and plat.counters["closed_no_fix"] == 1
        assert plat.chain.reason == "no_fix"


def test_valves_open_once_three_poses_agree_each_carried_by_its_age(pty_dev: Pty) -> None:
    ages: list[float] = []

    class Seen(GncChain):
        def update(self, now: float, *args: Any, **kwargs: Any) -> tuple[bool, ...]:
            if kwargs.get("fix") is not None:
                ages.append(kwargs["fix_age"])
            return super().update(now, *args, **kwargs)

    three = ONE_FIX.model_copy(
        update={"navigation": ONE_FIX.navigation.model_copy(update={"fixes_to_start": 3})}
    )  # three agreeing, the velocity's uncertainty not waited for (test_gnc.py)
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, chain=Seen(three)) as plat:
        assert three.navigation.fixes_to_start == 3
        for k in range(5):  # the IMU alone first: the motion known 50 ms back
            t = 0.95 + 0.01 * k
            pty_dev.send(encode_imu(t, 0.0, 0.0, 0.0))
            plat.step(t, AHEAD, 0.0)
        for k in range(3):
            t = 1.0 + 0.01 * k
            # Each POSE taken by the camera 30 ms before the IMU sample read with it.
            pty_dev.send(encode_imu(t, 0.0, 0.0, 0.0) + encode_pose(t - 0.03, Pose()))
            plat.step(t, AHEAD, 0.0)
            assert (plat.valves == POSITIVE_TORQUE) == (k == 2), k
        assert plat.counters["closed_no_fix"] == 5 + 2 and plat.chain.counters["fix_acquiring"] == 2
        assert ages == pytest.approx([0.03] * 3)
        # A POSE newer than the IMU: the chain takes it as of now.
        pty_dev.send(encode_imu(1.03, 0.0, 0.0, 0.0) + encode_pose(1.035, Pose()))
        plat.step(1.03, AHEAD, 0.0)
        assert ages[-1] == pytest.approx(-0.005) and plat.chain.counters["fix_rejected"] == 0
        # Its IMU frame lost: aged by the last one, read a step (0.01 s) before.
        pty_dev.send(encode_imu(1.05, 0.0, 0.0, 0.0))
        plat.step(1.04, AHEAD, 0.0)
        pty_dev.send(encode_pose(1.04, Pose()))
        plat.step(1.05, AHEAD, 0.0)
        assert ages[-1] == pytest.approx(0.01 + 0.01)
        # No IMU sample read for two steps: its age is not known, none is carried.
        plat.step(1.06, AHEAD, 0.0)
        pty_dev.send(encode_pose(1.045, Pose()))
        plat.step(1.07, AHEAD, 0.0)
        assert ages[-1] == 0.0


def test_garbage_and_bad_checksums_are_dropped_and_counted(pty_dev: Pty) -> None:
    pose = Pose(0.5, -0.25, 0.125, 0.0, 0.0, 0.0625)
    bad = bytearray(encode_imu(1.0, 9.0, 9.0, 9.0))
    bad[-2] ^= 0xFF
    garbage = b"\x00noise\xff\x5a"
    stream = (
        garbage
        + encode_pose(1.01, pose)  # read with the IMU sample of its time: no age
        + bytes(bad)
        + encode_imu(1.01, 0.0625, 0.0, 0.0)
        + garbage
        + encode_status(Status(1.02, 0, 2, 200, 0, 0, 0, 0, 0, 0))
    )
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(stream)
        got = plat.step(5.0, 1.0, 0.0)
        assert plat.device_pose == pose and plat.pose_time == 1.01
        # What it returns is the chain's estimate, which has taken the fix and the gyro.
        assert got == plat.pose == plat.chain.estimate
        assert (got.x, got.y, got.heading) == pytest.approx(pose[:3], abs=1e-3)
        assert got.omega == pytest.approx(0.0625)
        assert plat.imu == Imu(1.01, 0.0625, 0.0, 0.0)
        assert plat.status is not None and not plat.status.failsafe
        c = plat.counters
        print(f"host counters: {c}")
        assert c["frames_ok"] == 3
        assert c["bad_checksum"] == 1
        assert c["garbage_bytes"] == 2 * len(garbage) + len(bad)
        assert c["bytes_in"] == len(stream)
        assert plat.valves == POSITIVE_TORQUE
        assert pty_dev.received() == [Valves(0, 0b0000_0110), Heartbeat(0, 5.0)]


def test_hold_sends_all_closed_at_once_and_until_release(pty_dev: Pty) -> None:
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]
        pty_dev.send(encode_imu(0.01, 0.0, 0.0, 0.0))
        plat.hold()
        assert plat.valves == CLOSED and plat.held
        assert pty_dev.received() == [Valves(1, 0)]  # sent now, not at the next step
        plat.step(0.01, AHEAD, 0.0)
        assert _valves_of(pty_dev.received()) == [0]
        assert plat.counters["closed_held"] == 1
        plat.release()
        assert not plat.held
        plat.step(0.02, AHEAD, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]


def test_stale_pose_closes_the_valves(pty_dev: Pty) -> None:
    with SerialPlatform(
        pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX, pose_timeout=0.5
    ) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(10.0, AHEAD, 0.0)
        pty_dev.send(encode_imu(0.5, 0.0, 0.0, 0.0))  # the IMU goes on; the fixes stop
        plat.step(10.5, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        plat.step(10.51, AHEAD, 0.0)
        assert plat.valves == CLOSED
        assert plat.counters["closed_stale_fix"] == 1 and plat.chain.reason == "stale_fix"
        assert _valves_of(pty_dev.received()) == [0b110, 0b110, 0]


def test_a_failing_chain_closes_the_valves_before_raising(pty_dev: Pty) -> None:
    class Broken(GncChain):
        def update(self, now: float, *args: Any, **kwargs: Any) -> tuple[bool, ...]:
            if now > 0:
                raise ZeroDivisionError("gain schedule")
            return super().update(now, *args, **kwargs)

    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, chain=Broken(ONE_FIX)) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        with pytest.raises(ZeroDivisionError):
            plat.step(0.01, AHEAD, 0.0)
        assert plat.valves == CLOSED
        assert _valves_of(pty_dev.received()) == [0b110, 0]


def test_close_sends_all_closed_then_refuses_to_step(pty_dev: Pty) -> None:
    plat = SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX)
    pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
    plat.step(0.0, AHEAD, 0.0)
    plat.close()
    # The step's frame may still sit in the port's queue, which close() discards.
    assert _valves_of(pty_dev.received()) in ([0b110, 0], [0])
    assert plat.valves == CLOSED
    with pytest.raises(PlatformError, match="is closed"):
        plat.step(0.01, AHEAD, 0.0)
    plat.close()  # idempotent


def test_vanished_port_stops_actuation_with_a_clear_error(pty_dev: Pty) -> None:
    plat = SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX)
    try:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        pty_dev.close_master()  # the device is gone
        with pytest.raises(PlatformError, match=re.escape(f"serial port {pty_dev.path} vanished")):
            plat.step(0.01, AHEAD, 0.0)
        assert plat.valves == CLOSED
        with pytest.raises(PlatformError, match="vanished"):
            plat.step(0.02, AHEAD, 0.0)
        plat.hold()  # a safe hold on a dead port does not raise
    finally:
        plat.close()


def test_opening_a_missing_port_is_a_platform_error(tmp_path: Path) -> None:
    with pytest.raises(PlatformError, match=r"cannot open serial port .*nope"):
        SerialPlatform(str(tmp_path / "nope"))


def test_it_flies_the_gnc_chain_of_its_preset(pty_dev: Pty) -> None:
    """The chain of a simulated platform, built from the preset the agent names."""
    plat = make_platform(f"serial:{pty_dev.path}", preset="pinocchio")
    try:
        assert isinstance(plat, SerialPlatform) and isinstance(plat.chain, GncChain)
        assert isinstance(plat, Platform)
        assert plat.config == plat.chain.config == load_platform("pinocchio")
        assert plat.rate == plat.config.control.rate
        assert plat.chain.fix_timeout == plat.config.control.fix_timeout
    finally:
        plat.close()
    with SerialPlatform(
        pty_dev.path, write_timeout=WRITE_TIMEOUT
    ) as default:  # the default preset: knatte
        assert default.config == KNATTE
    # The fix wraps next to the estimate and the error wraps (Eq. 1): from 179 to -179
    # degrees is +2 degrees, a positive torque.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose(heading=3.124)))
        plat.step(0.0, -3.124, 0.0)
        assert plat.valves == POSITIVE_TORQUE
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, -AHEAD, 0.0)
        assert plat.valves == NEGATIVE_TORQUE


# -- the emulator as a process -------------------------------------------------
def _start_emulator(fleet: Fleet, name: str, tmp_path: Path, *extra: str) -> tuple[str, Path]:
    link = tmp_path / f"{name}-tty"
    record = tmp_path / f"{name}.jsonl"
    fleet.spawn(
        name,
        [*EMULATOR, "--link", str(link), "--record", str(record), "--duration", "60", *extra],
    )
    log = fleet.log_path(name)
    assert wait_for(lambda: "device on /dev/" in log.read_text(), 10.0, 0.02), log.read_text()
    assert link.is_symlink()
    path = re.search(r"device on (\S+)", log.read_text())
    assert path is not None and os.readlink(link) == path.group(1)
    return str(link), record


def _events(record: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in record.read_text().splitlines() if line.strip()]


class Clock:
    """Real-time pacing at the platform's rate, bounded by a step count."""

    def __init__(self, rate: float):
        self.period = 1.0 / rate
        self.start = time.monotonic()
        self.k = 0

    def tick(self) -> float:
        self.k += 1
        delay = self.start + self.k * self.period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        return self.k * self.period


LAG = 0.1  # s: how far apart in time the pty run and its twin may respond


def chase(plat: SerialPlatform) -> tuple[float, float]:
    """A reference always AHEAD of the estimate at its rate: +torque, saturated, every step."""
    est = plat.pose
    return est.heading + AHEAD, est.omega


@pytest.mark.timing  # the emulator paces itself on real time: a busy core delays its frames
def test_closed_loop_over_a_pty_converges_to_a_heading_step(fleet: Fleet, tmp_path: Path) -> None:
    """The serial loop flies the simulated platform's GNC: over the pty, the emulated
    KNATTE answers a heading step as the simulated KNATTE does (same preset, same seed)."""
    port, record = _start_emulator(fleet, "device", tmp_path, "--seed", "3")
    ref = 0.3  # rad, from t = 0.5 s
    plat = SerialPlatform(port)  # the GNC chain of knatte, as the emulator's default preset
    rows: list[tuple[float, float]] = []  # (t, heading estimate)
    try:
        clock = Clock(plat.rate)
        t = 0.0
        for _ in range(int(9.0 * plat.rate)):  # 9 s
            pose = plat.step(t, ref if t >= 0.5 else 0.0, 0.0)
            rows.append((t, pose.heading))
            t = clock.tick()
        counters = plat.counters
        # Then fire the +torque couple for a few steps, so that close() must change it
        # (the PWM reads a demand at each period's start: more than one period, 0.1 s).
        for _ in range(15):
            plat.step(t, *chase(plat))
            t = clock.tick()
        assert plat.valves[1] and plat.valves[2]
    finally:
        plat.close()
    simulated = SimulatedPlatform(KNATTE, seed=3)
    twin_rows = []
    for t, _ in rows:
        twin = simulated.step(t, ref if t >= 0.5 else 0.0, 0.0)
        twin_rows.append((t, twin.heading))
    # The same chain on the same plant, up to the line's timing: the emulator paces its
    # frames on real time, so its first fix, and with it the whole response, may come a
    # few periods later or earlier than the twin's. Each heading is compared with the
    # twin's over LAG either side (two of the emulator's 20 Hz fixes).
    apart = [
        min(abs(heading - h) for s, h in twin_rows if abs(s - t) <= LAG) for t, heading in rows
    ]
    settled_at = None
    for t, heading in rows:
        if t >= 0.5 and abs(heading - ref) < 0.05:
            settled_at = settled_at if settled_at is not None else t
            if t - settled_at >= 1.0:
                break
        else:
            settled_at = None
    took = "never" if settled_at is None else f"{settled_at - 0.5:.2f} s"
    print(
        f"heading step 0.3 rad over the pty: within 0.05 rad (for 1 s) after {took}, "
        f"final error {rows[-1][1] - ref:+.4f} rad (simulated twin "
        f"{twin.heading - ref:+.4f}); largest difference from the twin (within {LAG} s) "
        f"{max(apart):.4f} rad; "
        f"host counters {counters}"
    )
    assert settled_at is not None and settled_at - 0.5 < 7.0
    assert abs(rows[-1][1] - ref) < 0.05
    assert max(apart) < 0.02  # the same chain on the same plant
    assert counters["frames_ok"] > 300 and counters["bad_checksum"] == 0
    # Closed until the fixes agree and the velocity is known: 0.3 s of the emulator's
    # 20 Hz, and its first.
    assert counters["closed_stale_fix"] == 0 and counters["closed_no_fix"] <= 50
    # close() sent all-valves-closed: the device's last recorded command is mask 0.
    assert fleet.stop("device") == 0
    valves = [e for e in _events(record) if e["event"] == "valves"]
    assert valves[-2]["mask"] & 0b110 == 0b110  # the +torque couple (a push maybe beside)
    assert valves[-1]["mask"] == 0 and valves[-1]["applied"]


# The device's 200 ms heartbeat failsafe is a claim about real time: beside parallel tests
# a stall of either process for 0.2 s trips it (failing closed, as it should), and the
# valves the test then expects open are closed (ci177: after the release; ci175: the gap
# gained nothing).
@pytest.mark.timing
def test_faults_hold_heartbeat_loss_and_disconnect_over_a_pty(fleet: Fleet, tmp_path: Path) -> None:
    port, record = _start_emulator(
        fleet,
        "faulty",
        tmp_path,
        "--inject-garbage",
        "0.1",
        "--inject-bad-crc",
        "0.05",
        "--heartbeat-timeout-ms",
        "200",
        "--noise",
        "0",
    )
    plat = SerialPlatform(port)
    try:
        clock = Clock(plat.rate)
        t = 0.0

        def run(seconds: float) -> None:
            nonlocal t
            for _ in range(round(seconds * plat.rate)):
                plat.step(t, *chase(plat))
                t = clock.tick()

        # 1. Garbage and bad checksums on the line: dropped, counted, the loop goes on.
        run(1.5)
        c = plat.counters
        print(f"after 1.5 s with faults injected: {c}")
        assert c["frames_ok"] > 100
        assert c["bad_checksum"] > 0 and c["garbage_bytes"] > 0
        assert plat.status is not None and plat.status.valves & 0b110 == 0b110
        # 2. hold(): the device applies all-valves-closed.
        plat.hold()
        run(0.3)
        assert plat.status.valves == 0 and not plat.status.failsafe
        plat.release()
        run(0.3)
        assert plat.status.valves & 0b110 == 0b110

        def cut_writes() -> int:
            return plat.counters["write_timeouts"] + plat.counters["write_short"]

        # The gap's gain is the torque of the last command before it, for 0.2 s. On a
        # loaded host a write can be cut off, and the platform then sends all-closed (it
        # fails closed): a gap that began there gained nothing (ci148). And the chain does
        # not always command the bare +torque couple: with valve 0 open too the torque is
        # half (gained 0.041 to 0.044 rad/s in 4 runs of 6, against 0.1 ALPHA = 0.04), and a
        # step the chain closes (a late IMU sample) gives none (ci175: 0.0002). So run on,
        # 3 s at most, until a tenth of a second passes with no write cut off, the last step
        # commanded the couple alone, and the device reports valves 1 and 2 open.
        settled_by = t + 3.0
        while True:
            before = cut_writes()
            run(0.1)
            couple = plat.valves == POSITIVE_TORQUE
            if cut_writes() == before and couple and plat.status.valves & 0b110 == 0b110:
                break
            assert t < settled_by, f"no step of the couple alone: {plat.valves} {plat.counters}"
        # 3. Heartbeats stop for 0.5 s: the device closes every valve after 0.2 s.
        omega_before = plat.pose.omega
        time.sleep(0.5)
        clock = Clock(plat.rate)
        plat.step(t, *chase(plat))  # reads what the device sent during the silence
        gained = plat.pose.omega - omega_before
        print(
            f"heartbeat gap 0.5 s: omega gained {gained:.4f} rad/s "
            f"(0.2 s x {ALPHA} rad/s^2 = {0.2 * ALPHA:.2f}; without the failsafe "
            f"{0.5 * ALPHA:.2f})"
        )
        assert plat.counters["device_failsafe_reports"] > 0
        # (>= 1: a loaded machine that stalls either process for 0.2 s trips it too)
        assert plat.status.failsafe_trips >= 1
        # Torque stopped at the timeout (0.2 alpha, plus up to 0.05 alpha for the age of
        # the IMU sample read before the gap), not after 0.5 s (0.5 alpha).
        assert 0.1 * ALPHA < gained < 0.4 * ALPHA
        # 4. Disconnect: the emulator goes away; the next step raises, valves closed.
        assert fleet.stop("faulty") == 0
        with pytest.raises(PlatformError, match=re.escape(f"serial port {port} vanished")):
            for _ in range(10):
                plat.step(t, *chase(plat))
                t = clock.tick()
        assert plat.valves == CLOSED
    finally:
        plat.close()
    events = _events(record)
    kinds = [(e["event"], e.get("mask", e.get("active"))) for e in events]
    assert ("valves", 0) in kinds  # the hold
    assert ("failsafe", True) in kinds
    exit_event = events[-1]
    assert exit_event["event"] == "exit" and exit_event["failsafe_trips"] >= 1
    assert 0 < c["bad_checksum"] <= exit_event["injected_bad_crc"]


def test_emulate_device_command_help_and_signals(tmp_path: Path, fleet: Fleet) -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="fedlab", formatter_class=Formatter)
    sub = parser.add_subparsers(dest="command")
    emulate_device.add(sub)
    text = sub.choices["emulate-device"].format_help()
    assert "fedlab emulate-device" in text and "Example" in text
    assert "--platform" in text and "--torque-pair" in text
    assert "--connect" not in text  # no Zenoh session, no Zenoh flags
    args = parser.parse_args(["emulate-device", "--duration", "1"])
    assert callable(args.func) and args.platform == "knatte"
    # SIGINT stops cleanly with exit code 0, and the symlink goes away.
    port, _ = _start_emulator(fleet, "sigint", tmp_path)
    assert fleet.stop("sigint", sig=signal.SIGINT) == 0
    assert not Path(port).exists()
    # --duration ends it on its own; --platform names the preset it runs.
    proc = fleet.spawn("timed", [*EMULATOR, "--duration", "0.3", "--platform", "pinocchio"])
    assert proc.wait(10) == 0
    log = fleet.log_path("timed").read_text()
    assert "device on /dev/" in log and "(pinocchio)" in log


def test_emulate_device_rejects_bad_flags(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--mass", "-1"])
    assert exit_info.value.code == 2
    assert "positive" in capsys.readouterr().err
    # A preset that does not exist: a clear error, exit code 2, before any pty is opened.
    assert main(["--platform", "gustav"]) == 2
    assert "unknown platform 'gustav'" in capsys.readouterr().err


def test_scripted_frames_sent_by_the_host_are_the_documented_ones(pty_dev: Pty) -> None:
    # One step = VALVES then HEARTBEAT with the same seq: a write cut off between them
    # delivers no heartbeat that would keep the device's previous command alive.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode(DevicePose(0.0, Pose())))
        plat.step(2.5, -AHEAD, 0.0)
        time.sleep(0.02)
        raw = os.read(pty_dev.master, 4096)
    assert raw.startswith(encode_valves(0, 0b1001) + encode_heartbeat(0, 2.5))


# -- faults found in review ---------------------------------------------------------------
def test_a_hold_from_another_thread_during_a_step_is_the_last_word(pty_dev: Pty) -> None:
    """An abort arrives on Zenoh's thread while the loop's step is between the chain's
    open valves and their frame: the hold's all-closed must not be overwritten."""
    deciding, decided = threading.Event(), threading.Event()

    class Slow(GncChain):
        def update(self, now: float, *args: Any, **kwargs: Any) -> tuple[bool, ...]:
            valves = super().update(now, *args, **kwargs)
            if now > 0:
                deciding.set()
                decided.wait(0.05)  # the hold comes in meanwhile
            return valves

    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, chain=Slow(ONE_FIX)) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]

        def abort() -> None:
            deciding.wait(2.0)
            plat.hold()

        holder = threading.Thread(target=abort)
        holder.start()
        plat.step(0.01, AHEAD, 0.0)
        holder.join(2.0)
        decided.set()
        time.sleep(0.02)
        masks = _valves_of(pty_dev.received())
        assert masks[-1] == 0, masks  # the step's open mask first, then the hold's 0
        assert plat.held and plat.valves == CLOSED


def test_device_frames_not_newer_and_a_stale_backlog_are_not_fixes(pty_dev: Pty) -> None:
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(1.0, 0.0, 0.0, 0.0) + encode_pose(1.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        # The same POSE again (replayed) and an older IMU: dropped, counted.
        pty_dev.send(encode_imu(0.99, 0.0, 0.0, 0.0) + encode_pose(1.0, Pose(heading=AHEAD)))
        plat.step(0.01, AHEAD, 0.0)
        assert plat.counters["device_frames_not_newer"] == 2
        assert plat.device_pose == Pose()
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        # After a stall, a POSE 0.7 s older than the IMU before it (the device's clock):
        # not a fix of now, though it arrives now (on no timeline: dropped).
        pty_dev.send(encode_imu(5.0, 0.0, 0.0, 0.0) + encode_pose(4.3, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.counters["device_frames_off_timeline"] == 1
        assert plat.valves == CLOSED and plat.chain.reason == "no_fix"
        assert plat.counters["closed_no_fix"] == 1


def test_a_hold_whose_frame_times_out_is_not_confirmed(
    pty_dev: Pty, caplog: pytest.LogCaptureFixture
) -> None:
    import serial

    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        real = plat._serial.write

        def stuck(data: bytes) -> int:
            raise serial.SerialTimeoutException("Write timeout")

        plat._serial.write = stuck  # type: ignore[method-assign, assignment]
        with caplog.at_level("WARNING", logger="fedlab.serial"):
            plat.hold()
        # Closed is what was commanded; that the device applied it is not known.
        assert plat.held and plat.valves == CLOSED and not plat.valves_confirmed
        assert plat.counters["write_timeouts"] == 2  # the hold's, and its all-closed again
        assert "write timed out" in caplog.text and "not confirmed" in caplog.text
        plat._serial.write = real  # type: ignore[method-assign]
        pty_dev.send(encode_imu(0.01, 0.0, 0.0, 0.0))
        plat.step(0.01, AHEAD, 0.0)  # held: the 0 goes out again
        assert plat.valves == CLOSED and plat.valves_confirmed
        assert _valves_of(pty_dev.received())[-1] == 0


def test_a_flood_of_junk_is_read_a_bounded_amount_a_step(pty_dev: Pty) -> None:
    # Junk that keeps the decoder searching costs 1.5 us a byte under the platform's
    # lock, which an abort's hold waits for: 64 reads a step had held it 385 ms.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        reads: list[int] = []

        def talker(size: int = 1) -> bytes:  # a device that never stops sending junk
            reads.append(size)
            return bytes.fromhex("a55a0140") * (size // 4)

        plat._serial.read = talker  # type: ignore[method-assign, assignment]
        plat.step(0.0, AHEAD, 0.0)
        assert 0 < plat.counters["bytes_in"] <= 2 * 4096 and len(reads) <= 2, reads
        assert plat.valves == CLOSED


def test_a_backlog_in_the_devices_order_is_not_a_fix(pty_dev: Pty) -> None:
    # POSE(4.3) then the IMU samples that followed it, up to 5.0: read together after a
    # stall, the POSE was once judged against the IMU before it, and taken as a fix.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        backlog = encode_imu(4.29, 0.0, 0.0, 0.0) + encode_pose(4.3, Pose())
        backlog += b"".join(encode_imu(4.3 + 0.01 * k, 0.0, 0.0, 0.0) for k in range(1, 71))
        pty_dev.send(backlog)
        plat.step(0.0, AHEAD, 0.0)
        assert plat.counters["device_pose_stale"] == 1
        assert plat.valves == CLOSED and plat.chain.reason == "no_fix"


def _stream(t0: float, steps: int, poses: bool = True) -> list[bytes]:
    """A device at rest at the origin: per 10 ms step an IMU sample, and a POSE every
    50 ms (none without ``poses``), device times from ``t0``."""
    out = []
    for k in range(steps):
        t = round(t0 + 0.01 * k, 6)
        frame = encode_imu(t, 0.0, 0.0, 0.0)
        if poses and k % 5 == 0:
            frame += encode_pose(t, Pose())
        out.append(frame)
    return out


def test_an_old_pose_is_neither_a_restart_nor_a_fix(pty_dev: Pty) -> None:
    # Frames at device time 10.00 to 10.99, IMU(11.0), then a POSE of 8.99 (a replay, a
    # backlog): taken as a "device restart" and as a fix, it pulled the estimate to
    # x = 0.158 and opened valves 2 and 3 (position hold, KNATTE).
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        assert plat.chain.position_hold is not None
        host = 0.0
        for frames in _stream(10.0, 100):
            pty_dev.send(frames)
            plat.step(host, 0.0, 0.0)
            host += 0.01
        fixes, fix_time = plat.chain.filter.fixes, plat.chain.fix_time
        pty_dev.send(encode_imu(11.0, 0.0, 0.0, 0.0) + encode_pose(8.99, Pose(0.5, 0.0, 0.0)))
        plat.step(host, 0.0, 0.0)
        assert plat.chain.filter.fixes == fixes and plat.chain.fix_time == fix_time
        assert plat.pose_time == pytest.approx(10.95) and plat.device_pose == Pose()
        opened = []
        for frames in _stream(11.01, 50):
            host += 0.01
            pty_dev.send(frames)
            plat.step(host, 0.0, 0.0)
            opened.append(plat.valves != CLOSED)
        c = plat.counters
        assert c["device_restarts"] == 0 and c["device_frames_off_timeline"] == 1
        assert c["fix_rejected"] == 0  # never reached the chain
        assert not any(opened)
        assert abs(plat.pose.x) < 1e-3
        assert plat.chain.reason is None  # flying again on the device's clock


def test_a_device_that_restarts_is_heard_again_once_confirmed(pty_dev: Pty) -> None:
    # Its clock starts again from 0. Once every frame "not newer" kept the valves closed
    # for good; then the first old frame was a restart at once, and the chain kept its
    # estimate and fix time: valves opened on them before any POSE of the new clock.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        assert plat.chain.position_hold is not None
        pty_dev.send(encode_imu(100.0, 0.0, 0.0, 0.0) + encode_pose(100.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        assert plat.chain.position_hold.target == pytest.approx((0.0, 0.0), abs=1e-3)
        # It resets; its cameras see it at x = 0.3 (moved by hand meanwhile) at 0.15 s.
        reasons = []
        for k, frames in enumerate(_stream(0.0, 16, poses=False)):
            if k == 15:
                frames += encode_pose(0.15, Pose(0.3, 0.0, 0.0))
            pty_dev.send(frames)
            plat.step(0.01 * (k + 1), AHEAD, 0.0)
            reasons.append(plat.chain.reason)
            if k < 15:
                assert plat.valves == CLOSED, k
        # Nine frames on the new clock: not yet a restart; the tenth confirms it.
        assert reasons[:9] == ["device_restart"] * 9
        assert reasons[9:15] == ["no_fix"] * 6
        assert reasons[15] is None and plat.valves == POSITIVE_TORQUE
        c = plat.counters
        assert c["device_restarts"] == 1 and c["restarts"] == 1
        assert c["device_frames_off_timeline"] == 9 and c["device_frames_not_newer"] == 0
        assert plat.pose_time == 0.15
        # Position hold holds where the device now sees it, not where it was.
        assert plat.chain.position_hold.target == pytest.approx((0.3, 0.0), abs=1e-3)


def test_a_status_from_a_device_just_powered_up_confirms_its_restart(pty_dev: Pty) -> None:
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        pty_dev.send(encode_imu(100.0, 0.0, 0.0, 0.0) + encode_pose(100.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        # No HEARTBEAT since power-up (flags: FAILSAFE only): only a restarted device says so.
        powered_up = Status(0.0, 0, FLAG_FAILSAFE, 200, 0, 0, 0, 0, 0, 0)
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_status(powered_up))
        plat.step(0.01, AHEAD, 0.0)
        assert plat.counters["device_restarts"] == 1
        assert plat.valves == CLOSED and plat.chain.reason == "no_fix"
        assert plat.status == powered_up
        pty_dev.send(encode_imu(0.01, 0.0, 0.0, 0.0))
        plat.step(0.02, AHEAD, 0.0)
        assert plat.valves == CLOSED and plat.chain.reason == "no_fix"  # no POSE yet
        pty_dev.send(encode_imu(0.02, 0.0, 0.0, 0.0) + encode_pose(0.02, Pose()))
        plat.step(0.03, AHEAD, 0.0)
        assert plat.valves == POSITIVE_TORQUE


class CutOff:
    """A serial port whose next write sends the first ``keep`` bytes, then times out
    (pyserial raises ``SerialTimeoutException`` after a partial ``os.write``), or with
    ``short``, returns ``keep`` (a write aborted by ``cancel_write``)."""

    def __init__(self, real: Any, keep: int, short: bool = False):
        self.real, self.keep, self.short = real, keep, short
        self.armed = False
        self.calls: list[str] = []

    def write(self, data: bytes) -> int:
        import serial

        self.calls.append(f"write {len(data)}")
        if self.armed:
            self.armed = False
            self.real.write(data[: self.keep])
            if self.short:
                return self.keep
            raise serial.SerialTimeoutException("Write timeout")
        return int(self.real.write(data))

    def reset_output_buffer(self) -> None:
        self.calls.append("reset_output_buffer")
        self.real.reset_output_buffer()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.real, name)


@pytest.mark.parametrize("short", [False, True], ids=["timeout", "short"])
def test_a_write_cut_off_sends_no_heartbeat_and_closes_the_valves(
    pty_dev: Pty, short: bool
) -> None:
    # Cut 23 bytes into a step's frames: with HEARTBEAT (18 bytes) first, the device got
    # a heartbeat without its VALVES, feeding its failsafe on the previous command, and
    # the host reported that step's valves as applied.
    with SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX) as plat:
        port = CutOff(plat._serial, keep=23, short=short)
        plat._serial = port  # type: ignore[assignment]
        pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
        plat.step(0.0, AHEAD, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]
        port.armed = True
        pty_dev.send(encode_imu(0.01, 0.0, 0.0, 0.0))
        plat.step(0.01, AHEAD, 0.0)
        got = pty_dev.received()
        assert not any(isinstance(m, Heartbeat) for m in got), got
        # Its VALVES whole (unless the discarded queue still held it), then all closed.
        assert got in ([Valves(1, 0b110), Valves(2, 0)], [Valves(2, 0)])
        assert port.calls[-3:] == ["write 29", "reset_output_buffer", "write 81"]
        assert plat.valves == CLOSED and not plat.valves_confirmed
        c = plat.counters
        assert (c["write_short"], c["write_timeouts"]) == ((1, 0) if short else (0, 1))
        # The next step goes out whole: confirmed again.
        pty_dev.send(encode_imu(0.02, 0.0, 0.0, 0.0))
        plat.step(0.02, AHEAD, 0.0)
        assert pty_dev.received() == [Valves(3, 0b110), Heartbeat(3, 0.02)]
        assert plat.valves == POSITIVE_TORQUE and plat.valves_confirmed


def test_close_discards_the_output_queue_before_its_all_closed(pty_dev: Pty) -> None:
    # Frames queued in the port (a slow line) went out after close's all-closed frame
    # was written behind them; now they are discarded first.
    plat = SerialPlatform(pty_dev.path, write_timeout=WRITE_TIMEOUT, config=ONE_FIX)
    port = CutOff(plat._serial, keep=0)
    plat._serial = port  # type: ignore[assignment]
    pty_dev.send(encode_imu(0.0, 0.0, 0.0, 0.0) + encode_pose(0.0, Pose()))
    plat.step(0.0, AHEAD, 0.0)
    plat.close()
    assert port.calls == ["write 29", "reset_output_buffer", "write 81"]
    assert _valves_of(pty_dev.received())[-1] == 0
    assert plat.valves == CLOSED

"""The serial platform and the device emulator.

Three layers: the emulator's pure device (physics, failsafe timing, fault
injection) with ``now`` passed in; ``SerialPlatform`` against a scripted device
on a pseudo-terminal this test owns (exact counters, the frames it sends, a
vanished port); and ``fedlab emulate-device`` as a process with the platform
closing the heading loop over its pseudo-terminal. Every loop is bounded and
every process is stopped by pid (the ``fleet`` fixture).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import signal
import struct
import sys
import time
import tty
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from agents.serial.emulator import (
    BodyParams,
    EmulatedDevice,
    SensorNoise,
    register,
    thruster_wrench,
)
from agents.serial.platform import (
    CLOSED,
    NEGATIVE_TORQUE,
    POSITIVE_TORQUE,
    BangBangPD,
    PlatformError,
    SerialPlatform,
)
from agents.serial.protocol import (
    DEVICE_TO_HOST,
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
from federation import cli
from federation.core.wire import Pose
from federation.fleet.launch import Fleet, wait_for

EMULATOR = [sys.executable, "-m", "federation", "emulate-device"]
QUIET = SensorNoise().scaled(0.0)


def main(args: list[str]) -> int:
    """``fedlab emulate-device ARGS`` in this process."""
    return cli.main(["emulate-device", *args])


def f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


# -- the emulator's device, no I/O ---------------------------------------------
def test_thruster_couples_and_pairs() -> None:
    p = BodyParams()
    assert p.arm == pytest.approx(0.08)
    assert thruster_wrench(0b0000_0110, p) == pytest.approx((0.0, 0.0, 0.032))  # valves 1, 2
    assert thruster_wrench(0b0000_1001, p) == pytest.approx((0.0, 0.0, -0.032))  # valves 0, 3
    assert thruster_wrench(0b0000_0011, p) == pytest.approx((0.4, 0.0, 0.0))
    assert thruster_wrench(0b1100_0000, p) == pytest.approx((0.0, -0.4, 0.0))
    assert thruster_wrench(0xFF, p) == pytest.approx((0.0, 0.0, 0.0))


def test_thruster_geometry_matches_agents_dynamics() -> None:
    dyn = pytest.importorskip("agents.dynamics")
    theirs = dyn.BodyParams(mass=10.0, inertia=0.160, thrust=0.20, arm=0.08)
    for i in range(8):
        one_hot = [1.0 if j == i else 0.0 for j in range(8)]
        assert thruster_wrench(1 << i, BodyParams()) == pytest.approx(
            tuple(dyn.wrench(one_hot, theirs)), abs=1e-12
        ), f"valve {i}"


def _device(**kw: Any) -> EmulatedDevice:
    kw.setdefault("noise", QUIET)
    return EmulatedDevice(100.0, **kw)  # device time 0 is host time 100


def _run(device: EmulatedDevice, t0: float, t1: float, dt: float = 0.001) -> list[Message]:
    """Poll the device every ``dt`` from host time ``t0`` to ``t1``; decoded frames out."""
    decoder = FrameDecoder(DEVICE_TO_HOST)
    out: list[Message] = []
    for k in range(round((t1 - t0) / dt) + 1):
        out += decoder.feed(device.poll(t0 + k * dt))
    return out


def test_torque_couple_gives_the_rotation_the_inertia_predicts() -> None:
    device = _device()
    device.receive(encode_heartbeat(0, 0.0) + encode_valves(0, POSITIVE_TORQUE), 100.0)
    for k in range(1, 11):  # heartbeats every 50 ms for 0.5 s keep the valves open
        device.receive(encode_heartbeat(k, 0.05 * k), 100.0 + 0.05 * k)
    device.receive(encode_valves(11, CLOSED), 100.5)
    device.receive(encode_heartbeat(12, 1.0), 101.0)
    alpha = 0.032 / 0.160
    pose = device.pose
    print(f"torque pulse 0.5 s: omega {pose.omega:.6f} rad/s (predicted {alpha * 0.5:.6f})")
    assert pose.omega == pytest.approx(alpha * 0.5, rel=1e-9)
    # heading: 1/2 alpha t^2 during the pulse, then coasting for 0.5 s
    assert pose.heading == pytest.approx(0.5 * alpha * 0.25 + alpha * 0.5 * 0.5, rel=1e-9)
    assert (pose.x, pose.y, pose.vx, pose.vy) == pytest.approx((0, 0, 0, 0), abs=1e-15)


def test_push_pair_moves_along_the_body_axis() -> None:
    device = EmulatedDevice(0.0, noise=QUIET, initial=Pose(heading=math.pi / 2))
    device.receive(encode_heartbeat(0, 0.0) + encode_valves(0, 0b0000_0011), 0.0)  # +x body
    device.receive(encode_heartbeat(1, 0.1), 0.1)
    pose = device.pose
    # body +x is table +y at heading 90 degrees: a = 0.4 N / 10 kg
    assert pose.vy == pytest.approx(0.04 * 0.1, rel=1e-9)
    assert pose.vx == pytest.approx(0.0, abs=1e-12)
    assert pose.omega == 0.0


def test_device_stream_rates() -> None:
    frames = _run(_device(), 100.0, 101.0)
    imu = [m for m in frames if isinstance(m, Imu)]
    poses = [m for m in frames if isinstance(m, DevicePose)]
    status = [m for m in frames if isinstance(m, Status)]
    # 1 s with both ends included: 100 or 101 IMU frames, 20 or 21 POSE, 10 or 11 STATUS
    assert 100 <= len(imu) <= 101 and 20 <= len(poses) <= 21 and 10 <= len(status) <= 11
    gaps = [b.t - a.t for a, b in itertools.pairwise(imu)]
    assert max(gaps) == pytest.approx(0.010, abs=1.5e-3)
    assert status[0].failsafe  # no heartbeat yet: valves held closed


def test_failsafe_closes_valves_when_heartbeats_stop() -> None:
    events: list[dict[str, Any]] = []
    device = _device(heartbeat_timeout=0.2, on_event=events.append)
    decoder = FrameDecoder(DEVICE_TO_HOST)
    # Before any heartbeat, VALVES are ignored.
    device.receive(encode_valves(0, POSITIVE_TORQUE), 100.0)
    assert device.applied == 0 and device.valves_ignored == 1
    device.receive(encode_heartbeat(1, 0.0) + encode_valves(1, POSITIVE_TORQUE), 100.01)
    assert device.applied == 0b110 and not device.failsafe
    decoder.feed(device.poll(100.01))
    # Silence: open until 0.2 s after the heartbeat, closed from then on.
    decoder.feed(device.poll(100.2099))
    assert device.applied == 0b110
    frames = decoder.feed(device.poll(100.2101))
    assert device.failsafe and device.applied == 0 and device.failsafe_trips == 1
    status = [m for m in frames if isinstance(m, Status)]
    assert status and status[-1].failsafe and status[-1].valves == 0  # sent at once
    assert status[-1].failsafe_trips == 1
    # The valves closed exactly at the deadline: omega = alpha * 0.2 s.
    assert device.pose.omega == pytest.approx(0.2 * 0.2, rel=1e-9)
    # VALVES while in failsafe are ignored; a heartbeat clears it, valves stay closed...
    device.receive(encode_valves(2, POSITIVE_TORQUE), 100.3)
    device.receive(encode_heartbeat(3, 0.3), 100.31)
    assert not device.failsafe and device.applied == 0
    # ...until the next VALVES.
    device.receive(encode_valves(4, NEGATIVE_TORQUE), 100.32)
    assert device.applied == 0b1001
    assert [e["event"] for e in events] == ["valves", "failsafe", "failsafe", "failsafe", "valves"]
    assert [e.get("active") for e in events if e["event"] == "failsafe"] == [False, True, False]


def test_fault_injection_is_counted_exactly_by_the_host_decoder() -> None:
    device = _device(inject_garbage=0.2, inject_bad_crc=0.1)
    decoder = FrameDecoder(DEVICE_TO_HOST)
    for k in range(3001):
        decoder.feed(device.poll(100.0 + k * 0.001))
    print(f"injected: {device.counters}; host decoder: {decoder.counters}")
    assert device.injected_bad_crc > 10 and device.injected_garbage_bytes > 100
    assert decoder.bad_checksum == device.injected_bad_crc
    assert decoder.frames_ok == device.frames_sent - device.injected_bad_crc
    assert decoder.garbage_bytes >= device.injected_garbage_bytes


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
    with SerialPlatform(pty_dev.path, controller=lambda *a: POSITIVE_TORQUE) as plat:
        assert plat.step(0.0, 1.0, 0.0) == Pose()
        sent = pty_dev.received()
        assert sent == [Heartbeat(0, 0.0), Valves(0, 0)]
        assert plat.valves == CLOSED and plat.counters["closed_no_pose"] == 1


def test_garbage_and_bad_checksums_are_dropped_and_counted(pty_dev: Pty) -> None:
    pose = Pose(0.5, -0.25, 0.125, 0.0, 0.0, 0.0625)
    bad = bytearray(encode_imu(1.0, 9.0, 9.0, 9.0))
    bad[-2] ^= 0xFF
    garbage = b"\x00noise\xff\x5a"
    stream = (
        garbage
        + encode_pose(1.0, pose)
        + bytes(bad)
        + encode_imu(1.01, 0.0625, 0.0, 0.0)
        + garbage
        + encode_status(Status(1.02, 0, 2, 200, 0, 0, 0, 0, 0, 0))
    )
    with SerialPlatform(pty_dev.path, controller=lambda *a: POSITIVE_TORQUE) as plat:
        pty_dev.send(stream)
        got = plat.step(5.0, 1.0, 0.0)
        assert got == pose and plat.pose_time == 1.0
        assert plat.imu == Imu(1.01, 0.0625, 0.0, 0.0)
        assert plat.status is not None and not plat.status.failsafe
        c = plat.counters
        print(f"host counters: {c}")
        assert c["frames_ok"] == 3
        assert c["bad_checksum"] == 1
        assert c["garbage_bytes"] == 2 * len(garbage) + len(bad)
        assert c["bytes_in"] == len(stream)
        assert plat.valves == POSITIVE_TORQUE
        assert pty_dev.received() == [Heartbeat(0, 5.0), Valves(0, 0b0000_0110)]


def test_hold_sends_all_closed_at_once_and_until_release(pty_dev: Pty) -> None:
    with SerialPlatform(pty_dev.path, controller=lambda *a: POSITIVE_TORQUE) as plat:
        pty_dev.send(encode_pose(0.0, Pose()))
        plat.step(0.0, 0.0, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]
        plat.hold()
        assert plat.valves == CLOSED and plat.holding
        assert pty_dev.received() == [Valves(1, 0)]  # sent now, not at the next step
        plat.step(0.01, 0.0, 0.0)
        assert _valves_of(pty_dev.received()) == [0]
        plat.release()
        plat.step(0.02, 0.0, 0.0)
        assert _valves_of(pty_dev.received()) == [0b110]


def test_stale_pose_closes_the_valves(pty_dev: Pty) -> None:
    with SerialPlatform(
        pty_dev.path, controller=lambda *a: POSITIVE_TORQUE, pose_timeout=0.5
    ) as plat:
        pty_dev.send(encode_pose(0.0, Pose()))
        plat.step(10.0, 0.0, 0.0)
        plat.step(10.5, 0.0, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        plat.step(10.51, 0.0, 0.0)
        assert plat.valves == CLOSED
        assert _valves_of(pty_dev.received()) == [0b110, 0b110, 0]


def test_a_failing_controller_closes_the_valves_before_raising(pty_dev: Pty) -> None:
    def broken(t: float, ref: float, rate: float, pose: Pose) -> tuple[bool, ...]:
        if t > 0:
            raise ZeroDivisionError("gain schedule")
        return POSITIVE_TORQUE

    with SerialPlatform(pty_dev.path, controller=broken) as plat:
        pty_dev.send(encode_pose(0.0, Pose()))
        plat.step(0.0, 0.0, 0.0)
        with pytest.raises(ZeroDivisionError):
            plat.step(0.01, 0.0, 0.0)
        assert plat.valves == CLOSED
        assert _valves_of(pty_dev.received()) == [0b110, 0]


def test_close_sends_all_closed_then_refuses_to_step(pty_dev: Pty) -> None:
    plat = SerialPlatform(pty_dev.path, controller=lambda *a: POSITIVE_TORQUE)
    pty_dev.send(encode_pose(0.0, Pose()))
    plat.step(0.0, 0.0, 0.0)
    plat.close()
    assert _valves_of(pty_dev.received()) == [0b110, 0]
    assert plat.valves == CLOSED
    with pytest.raises(PlatformError, match="is closed"):
        plat.step(0.01, 0.0, 0.0)
    plat.close()  # idempotent


def test_vanished_port_stops_actuation_with_a_clear_error(pty_dev: Pty) -> None:
    plat = SerialPlatform(pty_dev.path, controller=lambda *a: POSITIVE_TORQUE)
    try:
        pty_dev.send(encode_pose(0.0, Pose()))
        plat.step(0.0, 0.0, 0.0)
        assert plat.valves == POSITIVE_TORQUE
        pty_dev.close_master()  # the device is gone
        with pytest.raises(PlatformError, match=re.escape(f"serial port {pty_dev.path} vanished")):
            plat.step(0.01, 0.0, 0.0)
        assert plat.valves == CLOSED
        with pytest.raises(PlatformError, match="vanished"):
            plat.step(0.02, 0.0, 0.0)
        plat.hold()  # a safe hold on a dead port does not raise
    finally:
        plat.close()


def test_opening_a_missing_port_is_a_platform_error(tmp_path: Path) -> None:
    with pytest.raises(PlatformError, match=r"cannot open serial port .*nope"):
        SerialPlatform(str(tmp_path / "nope"))


def test_bang_bang_pd_fires_the_couple_towards_the_reference() -> None:
    c = BangBangPD()
    assert c(0.0, 0.3, 0.0, Pose()) == POSITIVE_TORQUE
    assert c(0.0, -0.3, 0.0, Pose()) == NEGATIVE_TORQUE
    assert c(0.0, 0.005, 0.0, Pose()) == CLOSED  # inside the dead band
    # Braking: short of the target but turning fast towards it.
    assert c(0.0, 0.3, 0.0, Pose(heading=0.2, omega=0.2)) == NEGATIVE_TORQUE
    # The error wraps: from 179 to -179 degrees is +2 degrees.
    assert c(0.0, math.radians(-179), 0.0, Pose(heading=math.radians(179))) == POSITIVE_TORQUE


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


def test_closed_loop_over_a_pty_converges_to_a_heading_step(fleet: Fleet, tmp_path: Path) -> None:
    port, record = _start_emulator(fleet, "device", tmp_path, "--seed", "3")
    ref = 0.3  # rad, from t = 0.5 s
    plat = SerialPlatform(port)
    settled_at = None
    try:
        clock = Clock(plat.rate)
        t = 0.0
        for _ in range(int(9.0 * plat.rate)):  # at most 9 s
            pose = plat.step(t, ref if t >= 0.5 else 0.0, 0.0)
            if t >= 0.5 and abs(pose.heading - ref) < 0.02:
                settled_at = settled_at if settled_at is not None else t
                if t - settled_at >= 1.0:
                    break
            else:
                settled_at = None
            t = clock.tick()
        counters = plat.counters
        # Then fire the +torque couple for a few steps, so that close() must change it.
        plat.controller = lambda *a: POSITIVE_TORQUE
        for _ in range(5):
            plat.step(t, ref, 0.0)
            t = clock.tick()
    finally:
        plat.close()
    took = "never" if settled_at is None else f"{settled_at - 0.5:.2f} s"
    print(
        f"heading step 0.3 rad: within 0.02 rad (for 1 s) after {took}, "
        f"final error {pose.heading - ref:+.4f} rad; host counters {counters}"
    )
    assert settled_at is not None and settled_at - 0.5 < 7.0
    assert abs(pose.heading - ref) < 0.02
    assert counters["frames_ok"] > 300 and counters["bad_checksum"] == 0
    # close() sent all-valves-closed: the device's last recorded command is mask 0.
    assert fleet.stop("device") == 0
    valves = [e for e in _events(record) if e["event"] == "valves"]
    assert [e["mask"] for e in valves[-2:]] == [0b110, 0] and valves[-1]["applied"]


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
    plat = SerialPlatform(port, controller=lambda *a: POSITIVE_TORQUE)
    try:
        clock = Clock(plat.rate)
        t = 0.0

        def run(seconds: float) -> None:
            nonlocal t
            for _ in range(round(seconds * plat.rate)):
                plat.step(t, 0.0, 0.0)
                t = clock.tick()

        # 1. Garbage and bad checksums on the line: dropped, counted, the loop goes on.
        run(1.5)
        c = plat.counters
        print(f"after 1.5 s with faults injected: {c}")
        assert c["frames_ok"] > 100
        assert c["bad_checksum"] > 0 and c["garbage_bytes"] > 0
        assert plat.status is not None and plat.status.valves == 0b110
        # 2. hold(): the device applies all-valves-closed.
        plat.hold()
        run(0.3)
        assert plat.status.valves == 0 and not plat.status.failsafe
        plat.release()
        run(0.3)
        assert plat.status.valves == 0b110
        # 3. Heartbeats stop for 0.5 s: the device closes every valve after 0.2 s.
        omega_before = plat.pose.omega
        time.sleep(0.5)
        clock = Clock(plat.rate)
        plat.step(t, 0.0, 0.0)  # reads what the device sent during the silence
        gained = plat.pose.omega - omega_before
        print(f"heartbeat gap 0.5 s: omega gained {gained:.4f} rad/s (0.2 s x 0.2 rad/s^2 = 0.04)")
        assert plat.counters["device_failsafe_reports"] > 0
        # (>= 1: a loaded machine that stalls either process for 0.2 s trips it too)
        assert plat.status.failsafe_trips >= 1
        # Torque stopped at the timeout (0.04 rad/s, plus up to 0.01 for the age of the
        # pose read before the gap), not after 0.5 s (0.10 rad/s).
        assert 0.02 < gained < 0.08
        # 4. Disconnect: the emulator goes away; the next step raises, valves closed.
        assert fleet.stop("faulty") == 0
        with pytest.raises(PlatformError, match=re.escape(f"serial port {port} vanished")):
            for _ in range(10):
                plat.step(t, 0.0, 0.0)
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

    parser = argparse.ArgumentParser(prog="fedlab")
    sub = parser.add_subparsers(dest="command")
    register(sub, argparse.RawDescriptionHelpFormatter, lambda p: None)
    text = sub.choices["emulate-device"].format_help()
    assert "fedlab emulate-device" in text and "Example" in text
    assert "--connect" not in text  # no Zenoh session, no Zenoh flags
    args = parser.parse_args(["emulate-device", "--duration", "1"])
    assert callable(args.func)
    # SIGINT stops cleanly with exit code 0, and the symlink goes away.
    port, _ = _start_emulator(fleet, "sigint", tmp_path)
    assert fleet.stop("sigint", sig=signal.SIGINT) == 0
    assert not Path(port).exists()
    # --duration ends it on its own.
    proc = fleet.spawn("timed", [*EMULATOR, "--duration", "0.3"])
    assert proc.wait(10) == 0
    assert "device on /dev/" in fleet.log_path("timed").read_text()


def test_emulate_device_rejects_bad_flags(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--mass", "-1"])
    assert exit_info.value.code == 2
    assert "positive" in capsys.readouterr().err


def test_scripted_frames_sent_by_the_host_are_the_documented_ones(pty_dev: Pty) -> None:
    # One step = HEARTBEAT then VALVES with the same seq: the device's failsafe
    # clears before the command is read.
    with SerialPlatform(pty_dev.path, controller=lambda *a: NEGATIVE_TORQUE) as plat:
        pty_dev.send(encode(DevicePose(0.0, Pose())))
        plat.step(2.5, 0.0, 0.0)
        time.sleep(0.02)
        raw = os.read(pty_dev.master, 4096)
    assert raw.startswith(encode_heartbeat(0, 2.5) + encode_valves(0, 0b1001))

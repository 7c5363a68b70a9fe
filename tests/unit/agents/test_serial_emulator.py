"""The emulated device (agents/serial/emulator.py), with no I/O: ``now`` passed in.

Its physics and sensors are the simulated platform's :class:`~agents.simulated.Plant`
(agents.dynamics, agents.sensors), built from a platform preset; the protocol, the
failsafe timing and the fault injection are the device's own.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest

import agents.serial.emulator as emulator
from agents.dynamics import PAIRS, BodyParams, wrench
from agents.serial.emulator import EmulatedDevice, device_config
from agents.serial.protocol import (
    DEVICE_TO_HOST,
    DevicePose,
    FrameDecoder,
    Imu,
    Message,
    Status,
    encode_heartbeat,
    encode_valves,
    mask_to_valves,
    valves_to_mask,
)
from agents.simulated import Plant
from federation.core.wire import Pose
from schemas.base import ConfigError
from schemas.platform import load_platform

KNATTE = load_platform("knatte")
PINOCCHIO = load_platform("pinocchio")
QUIET = device_config(KNATTE, noise=0.0)  # KNATTE with perfect sensors
ALPHA = KNATTE.pair_torque / KNATTE.inertia  # rad/s^2 of a torque couple: 0.4
PLUS_TORQUE = valves_to_mask([i in PAIRS["+torque"] for i in range(8)])  # 0b0110
MINUS_TORQUE = valves_to_mask([i in PAIRS["-torque"] for i in range(8)])  # 0b1001


def _device(**kw: Any) -> EmulatedDevice:
    kw.setdefault("disturbance", False)
    return EmulatedDevice(100.0, kw.pop("config", QUIET), **kw)  # device time 0: host 100


def _run(device: EmulatedDevice, t0: float, t1: float, dt: float = 0.001) -> list[Message]:
    """Poll the device every ``dt`` from host time ``t0`` to ``t1``; decoded frames out."""
    decoder = FrameDecoder(DEVICE_TO_HOST)
    out: list[Message] = []
    for k in range(round((t1 - t0) / dt) + 1):
        out += decoder.feed(device.poll(t0 + k * dt))
    return out


# -- one model: the device's physics is agents.dynamics, through the simulated Plant -----
def test_the_device_carries_no_physics_of_its_own() -> None:
    for name in (
        "THRUSTERS",
        "BodyParams",
        "SensorNoise",
        "dynamics",
        "rk4_step",
        "thruster_wrench",
    ):
        assert not hasattr(emulator, name), name
    assert isinstance(_device().plant, Plant)


def test_emulated_device_and_plant_integrate_identically() -> None:
    """The same valve history gives bit-identical states, table slope included."""
    config = load_platform("knatte")  # disturbance on, noise on
    device = EmulatedDevice(100.0, config, seed=3, heartbeat_timeout=1.0)
    plant = Plant(config, seed=3, disturbance=True)
    script = [  # (host time, valve mask sent then)
        (100.0, PLUS_TORQUE),
        (100.37, 0b0000_0011),
        (100.52, MINUS_TORQUE | 0b0011_0000),
        (100.9, 0),
        (101.25, 0b1100_0000),
    ]
    last, mask = 100.0, 0
    for k, (now, new_mask) in enumerate(script):
        device.receive(encode_heartbeat(k, now) + encode_valves(k, new_mask), now)
        plant.advance(now - last, mask_to_valves(mask))
        plant.advance(0.0, mask_to_valves(new_mask))
        last, mask = now, new_mask
    device.poll(101.6)
    plant.advance(101.6 - last, mask_to_valves(mask))
    assert np.array_equal(device.plant.state, plant.state)
    assert device.plant.valves == plant.valves
    print(f"device and plant after 1.6 s: {plant.state.tolist()}")
    assert math.hypot(plant.state[0], plant.state[1]) > 1e-3  # it did move


def test_valve_masks_drive_the_dynamics_thrusters() -> None:
    body = BodyParams.from_config(KNATTE)
    assert wrench(mask_to_valves(PLUS_TORQUE), body) == pytest.approx((0, 0, KNATTE.pair_torque))
    assert wrench(mask_to_valves(MINUS_TORQUE), body) == pytest.approx((0, 0, -KNATTE.pair_torque))
    assert wrench(mask_to_valves(0b0000_0011), body) == pytest.approx((KNATTE.pair_force, 0, 0))
    assert wrench(mask_to_valves(0b1100_0000), body) == pytest.approx((0, -KNATTE.pair_force, 0))
    assert wrench(mask_to_valves(0xFF), body) == pytest.approx((0.0, 0.0, 0.0))


def test_torque_couple_gives_the_rotation_the_inertia_predicts() -> None:
    device = _device()
    device.receive(encode_heartbeat(0, 0.0) + encode_valves(0, PLUS_TORQUE), 100.0)
    for k in range(1, 11):  # heartbeats every 50 ms for 0.5 s keep the valves open
        device.receive(encode_heartbeat(k, 0.05 * k), 100.0 + 0.05 * k)
    device.receive(encode_valves(11, 0), 100.5)
    device.receive(encode_heartbeat(12, 1.0), 101.0)
    pose = device.pose
    print(f"torque pulse 0.5 s: omega {pose.omega:.6f} rad/s (predicted {ALPHA * 0.5:.6f})")
    assert pose.omega == pytest.approx(ALPHA * 0.5, rel=1e-9)
    # heading: 1/2 alpha t^2 during the pulse, then coasting for 0.5 s
    assert pose.heading == pytest.approx(0.5 * ALPHA * 0.25 + ALPHA * 0.5 * 0.5, rel=1e-9)
    assert (pose.x, pose.y, pose.vx, pose.vy) == pytest.approx((0, 0, 0, 0), abs=1e-15)


def test_push_pair_moves_along_the_body_axis() -> None:
    device = _device(initial=Pose(heading=math.pi / 2))
    device.receive(encode_heartbeat(0, 0.0) + encode_valves(0, 0b0000_0011), 100.0)  # +x body
    device.receive(encode_heartbeat(1, 0.1), 100.1)
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
    # PINOCCHIO's Vicon streams at its preset's 100 Hz
    vicon = _run(_device(config=PINOCCHIO), 100.0, 101.0)
    assert 100 <= sum(isinstance(m, DevicePose) for m in vicon) <= 101


def test_imu_and_pose_frames_are_the_presets_sensors() -> None:
    """IMU: the plant's gyro and accelerometers (bias and noise of the preset); POSE: a
    vision fix (noise of the preset, no rates), none outside the cameras' view."""
    device = _device(config=KNATTE, seed=1)
    frames = _run(device, 100.0, 110.0)
    gyro = np.array([m.gyro for m in frames if isinstance(m, Imu)])
    fixes = [m.pose for m in frames if isinstance(m, DevicePose)]
    i, v = KNATTE.imu, KNATTE.vision
    assert gyro.mean() == pytest.approx(i.gyro_bias, abs=5 * i.gyro_noise / math.sqrt(len(gyro)))
    assert gyro.std() == pytest.approx(i.gyro_noise, rel=0.1)
    headings = np.array([p.heading for p in fixes])
    assert headings.std() == pytest.approx(v.heading_noise, rel=0.15)
    assert all((p.vx, p.vy, p.omega) == (0.0, 0.0, 0.0) for p in fixes)
    # The thrust is sensed at once: +x pair, a = 2 F / m on the accelerometer.
    device.receive(encode_heartbeat(0, 0.0) + encode_valves(0, 0b0000_0011), 110.001)
    imu = [m for m in _run(device, 110.001, 110.2) if isinstance(m, Imu)]
    ax = np.mean([m.ax for m in imu])
    assert ax == pytest.approx(KNATTE.pair_force / KNATTE.mass + i.accel_bias[0], abs=0.01)
    # Outside the 3.0 x 1.7 m coverage: IMU still, no POSE.
    away = _device(initial=Pose(x=1.6))
    frames = _run(away, 100.0, 101.0)
    assert not any(isinstance(m, DevicePose) for m in frames)
    assert any(isinstance(m, Imu) for m in frames) and away.counters["fixes_unseen"] >= 20


def test_failsafe_closes_valves_when_heartbeats_stop() -> None:
    events: list[dict[str, Any]] = []
    device = _device(heartbeat_timeout=0.2, on_event=events.append)
    decoder = FrameDecoder(DEVICE_TO_HOST)
    # Before any heartbeat, VALVES are ignored.
    device.receive(encode_valves(0, PLUS_TORQUE), 100.0)
    assert device.applied == 0 and device.valves_ignored == 1
    device.receive(encode_heartbeat(1, 0.0) + encode_valves(1, PLUS_TORQUE), 100.01)
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
    assert device.pose.omega == pytest.approx(ALPHA * 0.2, rel=1e-9)
    # VALVES while in failsafe are ignored; a heartbeat clears it, valves stay closed...
    device.receive(encode_valves(2, PLUS_TORQUE), 100.3)
    device.receive(encode_heartbeat(3, 0.3), 100.31)
    assert not device.failsafe and device.applied == 0
    # ...until the next VALVES.
    device.receive(encode_valves(4, MINUS_TORQUE), 100.32)
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


# -- the preset and the emulator's overrides ------------------------------------------
def test_device_config_keeps_the_preset_without_overrides() -> None:
    assert device_config(PINOCCHIO) == PINOCCHIO


def test_device_config_overrides() -> None:
    c = device_config(
        KNATTE, mass=16.55, inertia=0.4002, thrust=0.7, torque_pair=0.3, imu_rate=50.0,
        pose_rate=1.0, noise=0.5,
    )  # fmt: skip
    assert (c.mass, c.inertia, c.thrust, c.imu.rate, c.vision.rate) == (
        16.55, 0.4002, 0.7, 50.0, 1.0,
    )  # fmt: skip
    assert c.pair_torque == pytest.approx(0.3) and c.max_torque >= c.torque
    assert c.max_thrust >= c.thrust
    assert c.imu.gyro_noise == pytest.approx(0.5 * KNATTE.imu.gyro_noise)
    assert c.imu.accel_bias == pytest.approx(tuple(0.5 * b for b in KNATTE.imu.accel_bias))
    assert c.vision.heading_noise == pytest.approx(0.5 * KNATTE.vision.heading_noise)
    quiet = device_config(KNATTE, noise=0.0)
    assert (quiet.imu.gyro_bias, quiet.vision.position_noise) == (0.0, 0.0)
    with pytest.raises(ConfigError, match="mass"):
        device_config(KNATTE, mass=-1.0)
    with pytest.raises(ValueError, match="noise"):
        device_config(KNATTE, noise=-1.0)


def test_device_checks_its_settings() -> None:
    with pytest.raises(ValueError, match="heartbeat_timeout"):
        _device(heartbeat_timeout=0.0)
    with pytest.raises(ValueError, match="inject_garbage"):
        _device(inject_garbage=1.5)

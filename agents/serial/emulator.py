"""An emulated platform's avionics: the serial protocol's device side over a simulated
platform (:class:`~agents.simulated.Plant`), with no I/O.

Bytes and ``now`` go in (:meth:`EmulatedDevice.receive`), frames come out
(:meth:`EmulatedDevice.poll`); :func:`agents.serial.pty.run_emulator` only moves bytes
between it and a pseudo-terminal, and ``fedlab emulate-device``
(``federation/cli/emulate_device.py``) builds it from a platform preset.

Physics and sensors
-------------------
Behind the protocol is the simulated platform's plant, built from the same
:class:`~schemas.platform.PlatformConfig`: :mod:`agents.dynamics` (the eight thrusters
of ``THRUSTERS``, the rigid body, RK4 at ``physics_rate``, the table's slope field when
``disturbance.enabled``) and :mod:`agents.sensors` (IMU noise and bias, vision noise and
coverage). A preset thus configures the emulated device and the simulated platform
alike, and the GNC chain (:mod:`agents.gnc`) meets the same platform in both.

The device streams

- IMU at ``imu.rate``: the plant's IMU sample (gyro, body specific force);
- POSE at ``vision.rate``: a metrology fix, the vision system's noisy x, y and heading
  with zero rates (a camera measures no rate); none while the platform is outside the
  cameras' coverage;
- STATUS at ``status_rate``, and at once on each failsafe change.

Failsafe
--------
The device holds every valve closed from its start until the first HEARTBEAT,
and again whenever no HEARTBEAT has arrived for ``heartbeat_timeout`` seconds.
VALVES commands received meanwhile are ignored; after heartbeats resume the
valves stay closed until the next VALVES command. Each failsafe change sends a
STATUS frame at once. The physics stops exactly at the failsafe deadline, so the
valves close on time whatever the polling.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import Any

from agents.serial.protocol import (
    FLAG_FAILSAFE,
    FLAG_HEARTBEAT_SEEN,
    HOST_TO_DEVICE,
    FrameDecoder,
    Heartbeat,
    Status,
    Valves,
    encode_imu,
    encode_pose,
    encode_status,
    mask_to_valves,
)
from agents.simulated import Plant
from federation.core.angles import wrap_angle
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.base import validate
from schemas.platform import PlatformConfig

__all__ = ["EmulatedDevice", "device_config"]


def device_config(
    base: PlatformConfig,
    *,
    mass: float | None = None,
    inertia: float | None = None,
    thrust: float | None = None,
    torque_pair: float | None = None,
    imu_rate: float | None = None,
    pose_rate: float | None = None,
    noise: float = 1.0,
) -> PlatformConfig:
    """``base`` with the emulator's overrides (None: the preset's value).

    Parameters
    ----------
    mass, inertia : float, optional
        kg and kg m^2.
    thrust : float, optional
        Force of one thruster, N (``max_thrust`` rises to it if needed).
    torque_pair : float, optional
        Torque of a thruster couple (two thrusters), Nm: the preset's ``torque`` is
        half of it (``max_torque`` rises to it if needed).
    imu_rate, pose_rate : float, optional
        IMU samples and metrology fixes per second, Hz.
    noise : float
        Factor on every sensor noise and bias (0: perfect sensors).

    Raises
    ------
    schemas.base.ConfigError
        A value the platform model refuses; the message names the field.
    """
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a factor >= 0, not {noise!r}")
    data = base.model_dump()
    _override_body(data, mass=mass, inertia=inertia, thrust=thrust, torque_pair=torque_pair)
    _override_rates(data, imu_rate=imu_rate, pose_rate=pose_rate)
    if noise != 1.0:
        _scale_noise(data, noise)
    return validate(PlatformConfig, data, f"emulated {base.name}")


def _override_body(
    data: dict[str, Any],
    *,
    mass: float | None,
    inertia: float | None,
    thrust: float | None,
    torque_pair: float | None,
) -> None:
    """The body and its thrusters in a preset's ``data``: each value given replaces
    the preset's, and a limit rises to a thrust or torque above it."""
    if mass is not None:
        data["mass"] = mass
    if inertia is not None:
        data["inertia"] = inertia
    if thrust is not None:
        data["thrust"] = thrust
        data["max_thrust"] = max(data["max_thrust"], thrust)
    if torque_pair is not None:
        data["torque"] = torque_pair / 2.0
        data["max_torque"] = max(data["max_torque"], data["torque"])


def _override_rates(
    data: dict[str, Any], *, imu_rate: float | None, pose_rate: float | None
) -> None:
    """The IMU's and the metrology's rates in a preset's ``data``."""
    if imu_rate is not None:
        data["imu"]["rate"] = imu_rate
    if pose_rate is not None:
        data["vision"]["rate"] = pose_rate
        # The device runs no controller; keep the preset valid at any fix rate.
        control = data["control"]
        control["fix_timeout"] = max(
            control["fix_timeout"], 2.0 / pose_rate + data["vision"]["latency_max"] + 0.1
        )


def _scale_noise(data: dict[str, Any], noise: float) -> None:
    """Every sensor noise and bias in a preset's ``data`` times ``noise``."""
    imu, vision = data["imu"], data["vision"]
    for key in ("gyro_noise", "gyro_bias", "accel_noise"):
        imu[key] *= noise
    imu["accel_bias"] = tuple(noise * b for b in imu["accel_bias"])
    for key in ("position_noise", "heading_noise"):
        vision[key] *= noise


_JUNK = bytes(b for b in range(256) if b != 0xA5)

_RX: dict[Count, Count] = {
    Count.FRAMES_OK: Count.RX_FRAMES_OK,
    Count.BAD_CHECKSUM: Count.RX_BAD_CHECKSUM,
    Count.GARBAGE_BYTES: Count.RX_GARBAGE_BYTES,
    Count.OVERSIZE: Count.RX_OVERSIZE,
    Count.UNKNOWN_TYPE: Count.RX_UNKNOWN_TYPE,
    Count.BAD_LENGTH: Count.RX_BAD_LENGTH,
    Count.BAD_VALUE: Count.RX_BAD_VALUE,
    Count.FRAME_BYTES: Count.RX_FRAME_BYTES,
    Count.BYTES_IN: Count.RX_BYTES_IN,
}
"""The device's counter of the host's frames for each of its decoder's."""


class EmulatedDevice:
    """The platform's avionics and physics; no I/O, ``now`` always passed in.

    Parameters
    ----------
    start : float
        Host clock reading that is device time 0 (s); ``now`` uses the same clock.
    config : PlatformConfig
        The platform: body, thrusters, sensors, table (see :func:`device_config`).
    seed : int
        Seed of the sensor noise (and, without ``rng``, of the fault injection).
    heartbeat_timeout : float
        Heartbeat silence (s) after which every valve is closed.
    status_rate : float
        STATUS frames per second.
    disturbance : bool, optional
        Table slope force; None: ``config.disturbance.enabled``.
    rng : random.Random, optional
        Draws of the fault injection.
    inject_garbage, inject_bad_crc : float
        Probability, per frame sent, of prepending 1 to 16 garbage bytes, and of
        corrupting the frame's CRC (fault injection for tests of the host).
    initial : Pose, optional
        Starting state (default: at rest at the origin).
    on_event : callable, optional
        Called with a JSON-ready dict on each valve command change and each
        failsafe change (for ``--record``).
    """

    def __init__(
        self,
        start: float,
        config: PlatformConfig,
        *,
        seed: int = 0,
        heartbeat_timeout: float = 0.2,
        status_rate: float = 10.0,
        disturbance: bool | None = None,
        rng: random.Random | None = None,
        inject_garbage: float = 0.0,
        inject_bad_crc: float = 0.0,
        initial: Pose | None = None,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ):
        for name, value in (("heartbeat_timeout", heartbeat_timeout), ("status_rate", status_rate)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, not {value!r}")
        for name, value in (("inject_garbage", inject_garbage), ("inject_bad_crc", inject_bad_crc)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], not {value!r}")
        self.start = start
        self.config = config
        self.heartbeat_timeout = heartbeat_timeout
        self.periods = (1.0 / config.imu.rate, 1.0 / config.vision.rate, 1.0 / status_rate)
        p = initial or Pose()
        if disturbance is None:
            disturbance = config.disturbance.enabled
        self.plant = Plant(config, seed, disturbance, p.x, p.y, p.heading)
        self.plant.state[3:] = (p.vx, p.vy, p.omega)
        self.rng = rng or random.Random(seed)
        self.inject_garbage = inject_garbage
        self.inject_bad_crc = inject_bad_crc
        self.on_event = on_event
        self.t = 0.0  # device time, s
        self.decoder = FrameDecoder(HOST_TO_DEVICE)
        self.applied = 0  # valve mask driving the thrusters
        self.commanded = 0  # last VALVES mask received
        self.valves_seq = 0
        self.heartbeat_seq = 0
        self.last_heartbeat: float | None = None  # device time
        self.failsafe = True  # until the first heartbeat
        self.failsafe_trips = 0
        self.valves_ignored = 0
        self.frames_sent = 0
        self.fixes_unseen = 0  # POSE frames not sent: outside the cameras' coverage
        self.injected_garbage_bytes = 0
        self.injected_bad_crc = 0
        self._due = [0.0, 0.0, 0.0]  # next IMU, POSE, STATUS (device time)
        self._status_now = False

    # -- inputs ----------------------------------------------------------------
    def receive(self, data: bytes, now: float) -> None:
        """Bytes from the host at ``now``: physics runs up to ``now``, then commands apply.

        Bytes count as arriving at ``now``: an emulator stalled past the heartbeat
        timeout trips its failsafe even if heartbeats were waiting, as firmware that
        polls its UART would.
        """
        self._advance(now)
        for message in self.decoder.feed(data):
            if isinstance(message, Heartbeat):
                self.heartbeat_seq = message.seq
                self.last_heartbeat = self.t
                if self.failsafe:
                    self.failsafe = False
                    self._status_now = True
                    self._event("failsafe", active=False)
            elif isinstance(message, Valves):
                self.valves_seq = message.seq
                if message.mask != self.commanded:
                    self._event(
                        "valves", seq=message.seq, mask=message.mask, applied=not self.failsafe
                    )
                self.commanded = message.mask
                if self.failsafe:
                    self.valves_ignored += 1
                else:
                    self._apply(message.mask)

    # -- outputs ---------------------------------------------------------------
    def poll(self, now: float) -> bytes:
        """Advance to ``now`` and return the frames due (at most one of each kind)."""
        self._advance(now)
        out = bytearray()
        t = self.t
        for kind in range(3):
            forced = kind == 2 and self._status_now
            if t < self._due[kind] and not forced:
                continue
            period = self.periods[kind]
            self._due[kind] += period
            if self._due[kind] <= t:  # fell behind (or first frame): restart the grid here
                self._due[kind] = t + period
            out += self._frame(kind)
        self._status_now = False
        return bytes(out)

    def next_deadline(self) -> float:
        """Next time (host clock) at which :meth:`poll` has something to do."""
        due = min(self._due)
        if self._status_now:
            due = self.t
        elif not self.failsafe and self.last_heartbeat is not None:
            due = min(due, self.last_heartbeat + self.heartbeat_timeout)
        return self.start + due

    @property
    def pose(self) -> Pose:
        """True pose, heading wrapped to (-pi, pi]."""
        x, y, psi, vx, vy, omega = self.plant.state.tolist()
        return Pose(x, y, wrap_angle(psi), vx, vy, omega)

    def status(self) -> Status:
        flags = (FLAG_FAILSAFE if self.failsafe else 0) | (
            FLAG_HEARTBEAT_SEEN if self.last_heartbeat is not None else 0
        )
        d = self.decoder
        return Status(
            t=self.t,
            valves=self.applied,
            flags=flags,
            heartbeat_timeout_ms=round(self.heartbeat_timeout * 1000),
            valves_seq=self.valves_seq,
            heartbeat_seq=self.heartbeat_seq,
            frames_ok=d.frames_ok,
            bad_checksum=d.bad_checksum,
            garbage_bytes=d.garbage_bytes,
            failsafe_trips=self.failsafe_trips,
        )

    @property
    def counters(self) -> dict[Count, int]:
        """Receive counters of host frames (``rx_*``) plus the device's own."""
        return {
            **{_RX[k]: v for k, v in self.decoder.counters.items()},
            Count.FRAMES_SENT: self.frames_sent,
            Count.FAILSAFE_TRIPS: self.failsafe_trips,
            Count.VALVES_IGNORED: self.valves_ignored,
            Count.FIXES_UNSEEN: self.fixes_unseen,
            Count.INJECTED_GARBAGE_BYTES: self.injected_garbage_bytes,
            Count.INJECTED_BAD_CRC: self.injected_bad_crc,
        }

    # -- internals -------------------------------------------------------------
    def _apply(self, mask: int) -> None:
        """Drive the thrusters with ``mask`` from now on (the IMU senses it at once)."""
        self.applied = mask
        self.plant.advance(0.0, mask_to_valves(mask))

    def _advance(self, now: float) -> None:
        target = now - self.start
        while True:
            self._check_heartbeat()
            if self.t >= target:
                return
            t_next = target
            if not self.failsafe and self.last_heartbeat is not None:
                # Stop exactly at the failsafe deadline, so the valves close on time.
                deadline = self.last_heartbeat + self.heartbeat_timeout
                if self.t < deadline < t_next:
                    t_next = deadline
            self.plant.advance(t_next - self.t, mask_to_valves(self.applied))
            self.t = t_next

    def _check_heartbeat(self) -> None:
        if self.failsafe or self.last_heartbeat is None:
            return
        if self.t - self.last_heartbeat >= self.heartbeat_timeout:
            self.failsafe = True
            self.failsafe_trips += 1
            self._apply(0)
            self._status_now = True
            self._event("failsafe", active=True, silent=self.t - self.last_heartbeat)

    def _event(self, name: str, **fields: Any) -> None:
        if self.on_event is not None:
            self.on_event({"t": round(self.t, 6), "event": name, **fields})

    def _frame(self, kind: int) -> bytes:
        if kind == 0:
            imu = self.plant.imu()
            frame = encode_imu(self.t, imu.gyro, imu.ax, imu.ay)
        elif kind == 1:
            fix = self.plant.vision()
            if fix is None:  # outside the cameras' view: no fix to send
                self.fixes_unseen += 1
                return b""
            frame = encode_pose(self.t, fix)
        else:
            frame = encode_status(self.status())
        self.frames_sent += 1
        if self.inject_bad_crc and self.rng.random() < self.inject_bad_crc:
            self.injected_bad_crc += 1
            frame = frame[:-1] + bytes((frame[-1] ^ 0x01,))
        if self.inject_garbage and self.rng.random() < self.inject_garbage:
            # 0xA5 left out: injected noise never starts a false sync, so counts stay exact.
            junk = bytes(self.rng.choice(_JUNK) for _ in range(self.rng.randint(1, 16)))
            self.injected_garbage_bytes += len(junk)
            frame = junk + frame
        return frame

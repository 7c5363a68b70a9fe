"""A real platform over a serial port (pyserial), speaking ``docs/serial-protocol.md``.

Each :meth:`SerialPlatform.step` (100 Hz) reads every byte waiting, decodes it
(:class:`~agents.serial.protocol.FrameDecoder`), keeps the device's latest
POSE, IMU and STATUS, runs the heading controller and sends a HEARTBEAT and a
VALVES frame. It never blocks on a read; a write waits at most ``write_timeout``.

Safety
------
- No valve opens before the device has sent a POSE, nor while its latest POSE is
  older than ``pose_timeout`` seconds of the agent's time.
- :meth:`~SerialPlatform.hold` closes every valve now and keeps them closed
  until :meth:`~SerialPlatform.release`; :meth:`~SerialPlatform.close` closes
  them and the port.
- A port that vanishes (unplugged cable, emulator gone: ``SerialException`` or
  ``OSError``) marks every valve closed and raises :class:`PlatformError`
  naming the port; the device's own heartbeat failsafe then closes its valves.
- A controller that raises gets an all-closed command sent before the error
  propagates.

Fallback controller
-------------------
:class:`BangBangPD` is a stand-in until ``agents/control.py`` (PID + PWM) is
done: a PD torque demand on the heading error (paper Eq. 1 and 2 without the
integral term) mapped bang-bang, with a dead band, onto the torque couples of
the thruster layout in ``agents/device_emulator.py`` (valves 1 and 2: +torque,
0 and 3: -torque, as ``agents.dynamics.PAIRS``). Pass ``controller=`` to use anything else.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

import serial

from agents.kinematic import PlatformError
from agents.serial.protocol import (
    DEVICE_TO_HOST,
    N_VALVES,
    DevicePose,
    FrameDecoder,
    Imu,
    Status,
    encode_heartbeat,
    encode_valves,
)
from federation.core.wire import Pose

__all__ = [
    "CLOSED",
    "NEGATIVE_TORQUE",
    "POSITIVE_TORQUE",
    "BangBangPD",
    "PlatformError",
    "SerialPlatform",
    "ValveController",
]

log = logging.getLogger("fedlab.serial")

ValveController = Callable[[float, float, float, Pose], tuple[bool, ...]]
"""``(t, heading_ref, rate_ref, pose) -> eight valve states``."""

CLOSED: tuple[bool, ...] = (False,) * N_VALVES
"""Every valve closed."""
POSITIVE_TORQUE: tuple[bool, ...] = (False, True, True, False, False, False, False, False)
"""Valves 1 and 2: the +torque couple (counter-clockwise), no net force."""
NEGATIVE_TORQUE: tuple[bool, ...] = (True, False, False, True, False, False, False, False)
"""Valves 0 and 3: the -torque couple, no net force."""

_U32 = 1 << 32
_READ_CHUNK = 4096
_MAX_READS = 64  # per step: bounds the time spent on a device that never stops talking


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass
class BangBangPD:
    """Fallback heading controller: PD torque demand, fired bang-bang on the torque couples.

    .. math::

        e = \\mathrm{wrap}(\\psi - \\psi_{ref}), \\qquad
        u = -\\left(K_p e + K_d (\\omega - \\omega_{ref})\\right)

    Valves 1 and 2 open when ``u > deadband`` (+torque), 0 and 3 when
    ``u < -deadband``, none otherwise. ``Kd / Kp`` (1.5 s) is the slope of the
    switching line; with KNATTE's 0.032 Nm couple it settles a 0.3 rad step to
    within 0.02 rad in about 4.5 s, without overshoot.
    To be replaced by ``agents/control.py`` (PID + PWM).
    """

    kp: float = 0.4  # Nm/rad
    kd: float = 0.6  # Nm s/rad
    deadband: float = 0.004  # Nm: 0.01 rad of heading error at rest

    def demand(self, heading_ref: float, rate_ref: float, pose: Pose) -> float:
        """Torque demand ``u``, Nm."""
        e = _wrap(pose.heading - heading_ref)  # paper Eq. 1
        return -(self.kp * e + self.kd * (pose.omega - rate_ref))

    def __call__(
        self, t: float, heading_ref: float, rate_ref: float, pose: Pose
    ) -> tuple[bool, ...]:
        u = self.demand(heading_ref, rate_ref, pose)
        if u > self.deadband:
            return POSITIVE_TORQUE
        if u < -self.deadband:
            return NEGATIVE_TORQUE
        return CLOSED


class SerialPlatform:
    """A platform whose avionics are on a serial port; a ``Platform`` for the agent runtime.

    Parameters
    ----------
    port : str
        Device path, e.g. ``/dev/ttyUSB0`` or an emulator's ``/dev/pts/7``.
    baudrate : int
        Line rate, bit/s (ignored by pseudo-terminals). 115200 leaves about 3x
        headroom over the protocol's ~3.8 kB/s downstream (docs/serial-protocol.md).
    controller : ValveController, optional
        ``(t, heading_ref, rate_ref, pose) -> 8 valve states``; default :class:`BangBangPD`.
    pose_timeout : float
        Agent seconds without a new POSE after which valves stay closed.
    write_timeout : float
        Longest wait for the port to take a step's frames, s. pyserial retries a
        full output buffer until it expires, so keep it a fraction of a step;
        a timeout is counted (``write_timeouts``), not raised: the device's
        failsafe covers a device that stops reading.
    rate : float
        Hz at which the agent is to call :meth:`step`.

    Raises
    ------
    PlatformError
        If the port cannot be opened.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        *,
        controller: ValveController | None = None,
        pose_timeout: float = 0.5,
        write_timeout: float = 0.005,
        rate: float = 100.0,
    ):
        self.port = port
        self.rate = rate
        self.pose_timeout = pose_timeout
        self.controller: ValveController = controller if controller is not None else BangBangPD()
        try:
            self._serial = serial.Serial(
                port,
                baudrate,
                timeout=0,
                write_timeout=write_timeout,
                exclusive=True if os.name == "posix" else None,
            )
        except (serial.SerialException, OSError, ValueError) as error:
            raise PlatformError(f"cannot open serial port {port}: {error}") from error
        self._decoder = FrameDecoder(DEVICE_TO_HOST)
        self._valves = CLOSED
        self._holding = False
        self._seq = 0
        self._failure: str | None = None
        self._new_pose = False  # a POSE arrived in this step's read
        self._pose_received_at: float | None = None  # agent time of the latest POSE
        self.pose = Pose()
        """Latest pose from the device (origin until the first POSE)."""
        self.pose_time: float | None = None
        """Device time of :attr:`pose`, s."""
        self.imu: Imu | None = None
        self.status: Status | None = None
        self._host = {
            "frames_sent": 0,
            "write_timeouts": 0,
            "closed_no_pose": 0,
            "device_failsafe_reports": 0,
        }

    # -- Platform ----------------------------------------------------------------
    def step(self, t: float, heading_ref: float, rate_ref: float) -> Pose:
        """Read, control, send HEARTBEAT and VALVES; return the device's latest pose.

        Raises
        ------
        PlatformError
            If the port has vanished or was closed; every valve is marked closed first.
            An exception from the controller propagates after an all-closed VALVES.
        """
        self._check_open()
        try:
            self._read()
        except (serial.SerialException, OSError) as error:
            self._vanished(error)
        try:
            valves = self._decide(t, heading_ref, rate_ref)
        except BaseException:
            self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
            raise
        seq = self._next_seq()
        self._send(encode_heartbeat(seq, t) + encode_valves(seq, valves), 2, valves)
        return self.pose

    def hold(self) -> None:
        """Close every valve now and keep them closed until :meth:`release`.

        Best effort: a port that has vanished is logged here and raised by the next
        :meth:`step` (the device's heartbeat failsafe closes its valves anyway).
        """
        self._holding = True
        self._valves = CLOSED
        if self._failure is None:
            try:
                self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
            except PlatformError as error:
                log.warning("hold: %s", error)

    def release(self) -> None:
        """End :meth:`hold`: the controller drives the valves again from the next step."""
        self._holding = False

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight valve states last commanded (all False after hold, close or a failure)."""
        return self._valves

    @property
    def holding(self) -> bool:
        return self._holding

    @property
    def counters(self) -> dict[str, int]:
        """Decoder counters (frames_ok, bad_checksum, garbage_bytes, ...) and the host's own."""
        return {**self._decoder.counters, **self._host}

    def close(self) -> None:
        """Send all-valves-closed (best effort) and close the port. Idempotent."""
        if self._failure is None:
            self._holding = True
            try:
                self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
            except PlatformError as error:
                log.warning("close: %s", error)
        self._valves = CLOSED
        if self._failure is None:
            self._failure = f"serial port {self.port} is closed"
        self._close_port()

    def __enter__(self) -> SerialPlatform:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------
    def _check_open(self) -> None:
        if self._failure is not None:
            raise PlatformError(self._failure)

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) % _U32
        return seq

    def _read(self) -> None:
        for _ in range(_MAX_READS):
            data = self._serial.read(_READ_CHUNK)
            if not data:
                return
            for message in self._decoder.feed(data):
                if isinstance(message, DevicePose):
                    self.pose = message.pose
                    self.pose_time = message.t
                    self._new_pose = True
                elif isinstance(message, Imu):
                    self.imu = message
                elif isinstance(message, Status):
                    self.status = message
                    if message.failsafe:
                        self._host["device_failsafe_reports"] += 1
            if len(data) < _READ_CHUNK:
                return

    def _decide(self, t: float, heading_ref: float, rate_ref: float) -> tuple[bool, ...]:
        if self._new_pose:
            self._new_pose = False
            self._pose_received_at = t
        if self._holding:
            return CLOSED
        if self._pose_received_at is None or t - self._pose_received_at > self.pose_timeout:
            self._host["closed_no_pose"] += 1
            return CLOSED
        valves = tuple(bool(v) for v in self.controller(t, heading_ref, rate_ref, self.pose))
        if len(valves) != N_VALVES:
            raise ValueError(f"controller returned {len(valves)} valve states, not {N_VALVES}")
        return valves

    def _send(self, frames: bytes, count: int, valves: tuple[bool, ...]) -> None:
        try:
            self._serial.write(frames)
        except serial.SerialTimeoutException:
            # The device is not draining the line; its own failsafe covers actuation.
            self._host["write_timeouts"] += 1
        except (serial.SerialException, OSError) as error:
            self._vanished(error)
        self._host["frames_sent"] += count
        self._valves = valves

    def _vanished(self, error: BaseException) -> None:
        self._valves = CLOSED
        self._failure = f"serial port {self.port} vanished: {error}"
        self._close_port()
        log.error("%s; valves marked closed", self._failure)
        raise PlatformError(self._failure) from error

    def _close_port(self) -> None:
        try:
            self._serial.close()
        except (serial.SerialException, OSError) as error:
            log.debug("closing %s: %s", self.port, error)

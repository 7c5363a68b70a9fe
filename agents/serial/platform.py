"""A real platform over a serial port (pyserial), speaking ``docs/serial-protocol.md``,
flown by the same GNC chain as a simulated platform (:mod:`agents.gnc`).

Each :meth:`SerialPlatform.step` (``control.rate``, 100 Hz) reads every byte waiting,
decodes it (:class:`~agents.serial.protocol.FrameDecoder`), hands the device's latest
IMU sample and POSE (a metrology fix) to the :class:`~agents.gnc.GncChain` built from
the platform's preset, and sends a HEARTBEAT and the chain's VALVES. It returns the
chain's navigation estimate, which the agent publishes. It never blocks on a read; a
write waits at most ``write_timeout``.

Safety
------
- No valve opens before the device has sent a POSE, nor while its latest POSE is
  older than ``pose_timeout`` seconds of the agent's time (the chain fails closed:
  ``reason`` ``no_fix`` or ``stale_fix``, counted in :attr:`SerialPlatform.counters`).
- :meth:`~SerialPlatform.hold` closes every valve now and keeps them closed
  until :meth:`~SerialPlatform.release`; :meth:`~SerialPlatform.close` closes
  them and the port.
- A port that vanishes (unplugged cable, emulator gone: ``SerialException`` or
  ``OSError``) marks every valve closed and raises :class:`PlatformError`
  naming the port; the device's own heartbeat failsafe then closes its valves.
- A chain that raises gets an all-closed command sent before the error propagates.
"""

from __future__ import annotations

import logging
import os
import threading
from types import TracebackType

import serial

from agents.gnc import CLOSED, GncChain
from agents.guidance import Track
from agents.interface import PlatformError
from agents.sensors import ImuSample
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
from schemas.platform import PlatformConfig, load_platform

__all__ = ["CLOSED", "PlatformError", "SerialPlatform"]

log = logging.getLogger("fedlab.serial")

_U32 = 1 << 32
_READ_CHUNK = 4096
_MAX_READS = 64  # per step: bounds the time spent on a device that never stops talking


class SerialPlatform:
    """A platform whose avionics are on a serial port, under the GNC chain; a
    :class:`~agents.platform.Platform` for the agent runtime.

    Parameters
    ----------
    port : str
        Device path, e.g. ``/dev/ttyUSB0`` or an emulator's ``/dev/pts/7``.
    config : PlatformConfig, optional
        The platform's preset: what the chain's filter, PID, PWM and allocation are
        built for; None: ``knatte``.
    baudrate : int
        Line rate, bit/s (ignored by pseudo-terminals). 115200 leaves about 3x
        headroom over the protocol's ~3.8 kB/s downstream (docs/serial-protocol.md).
    pose_timeout : float, optional
        Agent seconds without a new POSE after which valves stay closed; None:
        ``config.control.fix_timeout``.
    write_timeout : float
        Longest wait for the port to take a step's frames, s. pyserial retries a
        full output buffer until it expires, so keep it a fraction of a step;
        a timeout is counted (``write_timeouts``), not raised: the device's
        failsafe covers a device that stops reading.
    chain : GncChain, optional
        The chain to fly (tests); None: one built from ``config``.

    Raises
    ------
    PlatformError
        If the port cannot be opened.
    """

    def __init__(
        self,
        port: str,
        config: PlatformConfig | None = None,
        baudrate: int = 115200,
        *,
        pose_timeout: float | None = None,
        write_timeout: float = 0.005,
        chain: GncChain | None = None,
    ):
        self.port = port
        self.config: PlatformConfig = config if config is not None else load_platform("knatte")
        self.chain = chain or GncChain(self.config, fix_timeout=pose_timeout)
        self.rate: float = self.chain.rate
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
        # One writer at a time: a hold from another thread (an abort arriving on Zenoh's)
        # between the chain's open valves and their frame would be overwritten by them.
        self._lock = threading.RLock()
        self._valves = CLOSED
        self._seq = 0
        self._failure: str | None = None
        self._new_imu: ImuSample | None = None  # the latest IMU of this step's read
        self._new_fix: Pose | None = None  # the latest POSE of this step's read
        self.device_pose: Pose | None = None
        """Latest POSE from the device (None until the first)."""
        self.pose_time: float | None = None
        """Device time of :attr:`device_pose`, s."""
        self.imu: Imu | None = None
        self.status: Status | None = None
        self._host = {
            "frames_sent": 0,
            "write_timeouts": 0,
            "device_failsafe_reports": 0,
            "device_frames_not_newer": 0,
            "device_pose_stale": 0,
            "device_restarts": 0,
        }

    # -- Platform ----------------------------------------------------------------
    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """Read, run the chain, send HEARTBEAT and VALVES; return the navigation estimate.

        ``track``: a 3-DOF position reference (table frame) for the chain, if any.

        Raises
        ------
        PlatformError
            If the port has vanished or was closed; every valve is marked closed first.
            An exception from the chain propagates after an all-closed VALVES.
        """
        with self._lock:
            self._check_open()
            try:
                self._read()
            except (serial.SerialException, OSError) as error:
                self._vanished(error)
            imu, fix = self._new_imu, self._new_fix
            self._new_imu = self._new_fix = None
            chain = self.chain
            try:
                valves = tuple(
                    bool(v)
                    for v in chain.update(t, heading_ref, rate_ref, imu=imu, fix=fix, track=track)
                )
                if len(valves) != N_VALVES:
                    raise ValueError(f"the chain gave {len(valves)} valve states, not {N_VALVES}")
            except BaseException:
                self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
                raise
            seq = self._next_seq()
            self._send(encode_heartbeat(seq, t) + encode_valves(seq, valves), 2, valves)
            return chain.estimate

    def hold(self) -> None:
        """Close every valve now and keep them closed until :meth:`release`.

        Best effort: a port that has vanished is logged here and raised by the next
        :meth:`step` (the device's heartbeat failsafe closes its valves anyway).
        """
        with self._lock:
            self._close_valves("hold")
            if self._failure is not None:
                self._valves = CLOSED  # the port is gone: the device's failsafe closed them

    def release(self) -> None:
        """End :meth:`hold`: the chain drives the valves again from the next step."""
        self.chain.release()

    @property
    def held(self) -> bool:
        return self.chain.held

    @property
    def pose(self) -> Pose:
        """The chain's navigation estimate (what :meth:`step` returned last)."""
        return self.chain.estimate

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight valve states last commanded (all False after hold, close or a failure)."""
        return self._valves

    @property
    def counters(self) -> dict[str, int]:
        """Decoder counters (frames_ok, bad_checksum, garbage_bytes, ...), the host's own
        and the chain's closed steps (closed_no_fix, closed_stale_fix, closed_held)."""
        return {**self._decoder.counters, **self._host, **self.chain.counters}

    def close(self) -> None:
        """Send all-valves-closed (best effort) and close the port. Idempotent."""
        with self._lock:
            self._close_valves("close")
            self._valves = CLOSED  # closed port: the device's heartbeat failsafe closes them
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
    def _close_valves(self, why: str) -> None:
        """Hold the chain and send all-closed at once (best effort on a live port)."""
        self.chain.hold()
        if self._failure is None:
            try:
                self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
            except PlatformError as error:
                log.warning("%s: %s", why, error)

    def _check_open(self) -> None:
        if self._failure is not None:
            raise PlatformError(self._failure)

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) % _U32
        return seq

    def _read(self) -> None:
        self._read_frames()
        # Judged once everything waiting is read: a backlog comes in the device's order,
        # its POSE before the IMU samples that followed it.
        if (
            self._new_fix is not None
            and self.imu is not None
            and self.pose_time is not None
            and self.imu.t - self.pose_time > self.chain.fix_timeout
        ):
            self._host["device_pose_stale"] += 1  # older than the fix timeout: not a fix of now
            self._new_fix = None

    def _read_frames(self) -> None:
        for _ in range(_MAX_READS):
            data = self._serial.read(_READ_CHUNK)
            if not data:
                return
            for message in self._decoder.feed(data):
                if isinstance(message, DevicePose):
                    last = self.pose_time
                    if (
                        last is not None
                        and message.t <= last
                        and not self._device_restarted(last - message.t)
                    ):
                        self._host["device_frames_not_newer"] += 1  # replayed or reordered
                        continue
                    self.device_pose = message.pose
                    self.pose_time = message.t
                    self._new_fix = message.pose
                elif isinstance(message, Imu):
                    imu = self.imu
                    if (
                        imu is not None
                        and message.t <= imu.t
                        and not self._device_restarted(imu.t - message.t)
                    ):
                        self._host["device_frames_not_newer"] += 1
                        continue
                    self.imu = message
                    self._new_imu = ImuSample(message.gyro, message.ax, message.ay)
                elif isinstance(message, Status):
                    self.status = message
                    if message.failsafe:
                        self._host["device_failsafe_reports"] += 1
            if len(data) < _READ_CHUNK:
                return

    def _device_restarted(self, back: float) -> bool:
        """A frame ``back`` s older than the last of its kind: a device whose clock went
        back by more than the fix timeout has restarted (a reset, a brownout), and its
        frames from now on are new. Anything less is a replay or a reordering."""
        if back <= self.chain.fix_timeout:
            return False
        self._host["device_restarts"] += 1
        log.warning("serial device on %s restarted (its clock went back %.3f s)", self.port, back)
        self.pose_time = None
        self.imu = None
        self._new_fix = None
        self._new_imu = None
        return True

    def _send(self, frames: bytes, count: int, valves: tuple[bool, ...]) -> None:
        try:
            self._serial.write(frames)
        except serial.SerialTimeoutException:
            # The device is not draining the line: what it applies is unknown, so the
            # valves last commanded stay as they were; a hold sends its 0 again at every
            # step, and the device's heartbeat failsafe covers a line that stays stuck.
            self._host["write_timeouts"] += 1
            if (
                self._host["write_timeouts"] in (1, 10, 100)
                or self._host["write_timeouts"] % 1000 == 0
            ):
                log.warning(
                    "serial port %s: write timed out (%d so far); valves %s not confirmed",
                    self.port, self._host["write_timeouts"], _mask_text(valves),
                )  # fmt: skip
            return
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


def _mask_text(valves: tuple[bool, ...]) -> str:
    return "all closed" if not any(valves) else "".join("1" if v else "0" for v in valves)

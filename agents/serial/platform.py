"""A real platform over a serial port (pyserial), speaking ``docs/serial-protocol.md``,
flown by the same GNC chain as a simulated platform (:mod:`agents.gnc`).

Each :meth:`SerialPlatform.step` (``control.rate``, 100 Hz) reads every byte waiting,
decodes it (:class:`~agents.serial.protocol.FrameDecoder`), hands the device's latest
IMU sample and POSE (a metrology fix) to the :class:`~agents.gnc.GncChain` built from
the platform's preset, and sends the chain's VALVES, then a HEARTBEAT with the same
``seq``. It returns the chain's navigation estimate, which the agent publishes. It
never blocks on a read; a write waits at most ``write_timeout``.

Safety
------
- No valve opens before the device has sent POSEs that agree (``fixes_to_start``), nor
  while its latest POSE is older than ``pose_timeout`` seconds of the agent's time
  (the chain fails closed: ``reason`` ``no_fix`` or ``stale_fix``, counted in
  :attr:`SerialPlatform.counters`). A POSE is carried forward by the motion since it
  was measured: the device's IMU time minus its time (:mod:`agents.gnc`).
- :meth:`~SerialPlatform.hold` closes every valve now and keeps them closed
  until :meth:`~SerialPlatform.release`; :meth:`~SerialPlatform.close` closes
  them and the port.
- A port that vanishes (unplugged cable, emulator gone: ``SerialException`` or
  ``OSError``) marks every valve closed and raises :class:`PlatformError`
  naming the port; the device's own heartbeat failsafe then closes its valves.
- A chain that raises gets an all-closed command sent before the error propagates.
- The chain rejects a POSE outside the table or far from its estimate (``fix_rejected``;
  :mod:`agents.gnc`).
- Frames are judged on the device's clock (:class:`~agents.serial.timeline.DeviceTimeline`):
  one not newer than the last of its kind is dropped (``device_frames_not_newer``), one
  more than ``pose_timeout`` older than the device's newest is on no timeline and
  dropped (``device_frames_off_timeline``): a replayed old POSE is never a fix. The
  device restarted (its clock began again) only once ``restart_frames`` frames in a row,
  or a STATUS saying it has had no heartbeat since power-up and one more frame, are on
  the new timeline;
  meanwhile every valve stays closed (``device_restart``). A confirmed restart
  (``device_restarts``) restarts the chain's estimate: closed (``no_fix``) until a POSE
  of the new timeline, and position hold re-takes its point there.
- VALVES go before the HEARTBEAT that vouches for them: a write cut off never delivers a
  heartbeat keeping the device's previous command alive. A write that times out or
  stops short (``write_timeouts``, ``write_short``) discards the port's output queue
  (frames queued there would go out later), sends filler that completes any frame cut
  off on the line and an all-closed VALVES, and reports the valves closed, unconfirmed
  (:attr:`SerialPlatform.valves_confirmed`). :meth:`~SerialPlatform.close` discards the
  queue the same way before its all-closed frame.
"""

from __future__ import annotations

import logging
import os
import threading
from types import TracebackType

import serial

from agents.gnc import CLOSED, GncChain, PlatformReason
from agents.guidance import Track
from agents.interface import PlatformError, WithChain
from agents.platform import DEFAULT_SERIAL_PRESET
from agents.sensors import ImuSample
from agents.serial.protocol import (
    DEVICE_TO_HOST,
    FLAG_HEARTBEAT_SEEN,
    MAX_PAYLOAD,
    N_VALVES,
    OVERHEAD,
    DevicePose,
    FrameDecoder,
    Imu,
    Status,
    encode_heartbeat,
    encode_valves,
)
from agents.serial.timeline import DeviceTimeline, Kind
from federation.core.counters import Count
from federation.core.wire import Pose
from schemas.platform import PlatformConfig, load_platform

__all__ = ["CLOSED", "PlatformError", "SerialPlatform"]

log = logging.getLogger("fedlab.serial")

_U32 = 1 << 32
_READ_CHUNK = 4096
# Per step: bounds the time spent decoding under the platform's lock, which a hold from
# another thread (an abort) waits for. A device that never stops talking, or junk that
# keeps the decoder searching (1.5 us a byte: 64 reads had held the lock 385 ms), then
# waits in the port's buffer; its frames grow old there and are dropped as such, the
# valves closed for stale data. A real link brings about 115 bytes a step at 115200 baud.
_MAX_READS = 2
# Sent before the all-closed VALVES after a write cut off: completes any frame left
# half-sent on the line (its CRC then fails), so the device decodes the VALVES at once.
# No 0xA5 in it: never a false sync.
_FILLER = bytes(MAX_PAYLOAD + OVERHEAD)


def _rate_limited(count: int) -> bool:
    """Log the 1st, 10th, 100th and every 1000th of a recurring event."""
    return count in (1, 10, 100) or count % 1000 == 0


class SerialPlatform(WithChain):
    """A platform whose avionics are on a serial port, under the GNC chain; a
    :class:`~agents.platform.Platform` for the agent runtime (its chain's fix, restart
    and causes: :class:`~agents.interface.WithChain`).

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
    restart_frames : int
        Frames in a row on a new device timeline that confirm the device restarted
        (without a STATUS saying so): 10 is 0.1 s of IMU at 100 Hz.
    chain : GncChain, optional
        The chain to fly (tests); None: one built from ``config``.

    Raises
    ------
    PlatformError
        If the port cannot be opened.
    """

    kind = "serial"
    """Its name in an agent's ``platform`` spec: ``serial:PORT``."""
    argument = "PORT"
    hardware = True

    @classmethod
    def check_spec(cls, argument: str | None) -> None:
        """A port is given (whether it opens is known when the agent starts)."""
        if not argument:
            raise ValueError("serial platform needs a port: serial:/dev/ttyUSB0")

    @classmethod
    def from_spec(
        cls, argument: str | None, *, seed: int, rate: float, preset: str | None
    ) -> SerialPlatform:
        """The avionics on port ``argument`` under the GNC chain of ``preset`` (a name or
        a file; None: :data:`~agents.platform.DEFAULT_SERIAL_PRESET`). PlatformError if
        the port does not open."""
        cls.check_spec(argument)
        assert argument is not None
        return cls(argument, load_platform(preset or DEFAULT_SERIAL_PRESET))

    def __init__(
        self,
        port: str,
        config: PlatformConfig | None = None,
        baudrate: int = 115200,
        *,
        pose_timeout: float | None = None,
        write_timeout: float = 0.005,
        restart_frames: int = 10,
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
        self._timeline = DeviceTimeline(self.chain.fix_timeout, restart_frames)
        # One writer at a time: a hold from another thread (an abort arriving on Zenoh's)
        # between the chain's open valves and their frame would be overwritten by them.
        self._lock = threading.RLock()
        self._valves = CLOSED
        self.valves_confirmed: bool = True
        """False after a write that timed out or stopped short, until one goes out whole:
        :attr:`valves` is then what was commanded (all closed), not known to be applied."""
        self._seq = 0
        self._cut_offs = 0  # writes cut off (each counted once, with its resend)
        self._failure: str | None = None
        self._new_imu: ImuSample | None = None  # the latest IMU of this step's read
        self._new_fix: Pose | None = None  # the latest POSE of this step's read
        self._imu_fresh = 0  # steps ago an IMU sample was read (0: this one)
        self._imu_step = 0.0  # the step's time when it was
        self.device_pose: Pose | None = None
        """Latest POSE from the device (None until the first)."""
        self.pose_time: float | None = None
        """Device time of :attr:`device_pose`, s."""
        self.imu: Imu | None = None
        self.status: Status | None = None
        self._host = {
            Count.FRAMES_SENT: 0,
            Count.WRITE_TIMEOUTS: 0,
            Count.DEVICE_FAILSAFE_REPORTS: 0,
            Count.DEVICE_FRAMES_NOT_NEWER: 0,
            Count.DEVICE_FRAMES_OFF_TIMELINE: 0,
            Count.DEVICE_POSE_STALE: 0,
            Count.DEVICE_RESTARTS: 0,
            Count.WRITE_SHORT: 0,
        }

    # -- Platform ----------------------------------------------------------------
    def step(
        self, t: float, heading_ref: float, rate_ref: float, track: Track | None = None
    ) -> Pose:
        """Read, run the chain, send VALVES and HEARTBEAT; return the navigation estimate.

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
                self._read(t)
            except (serial.SerialException, OSError) as error:
                self._vanished(error)
            imu, fix = self._new_imu, self._new_fix
            self._new_imu = self._new_fix = None
            # The POSE lags the IMU read with it by the metrology's latency (the device's
            # clock). Only an IMU sample of this read or the last: one frame timed ahead
            # (on the timeline still) would otherwise age every POSE until real ones pass
            # it; a POSE read alone (its IMU frame lost) would go uncarried.
            self._imu_fresh = 0 if imu is not None else self._imu_fresh + 1
            if imu is not None:
                self._imu_step = t  # the chain's time for that sample
            age = 0.0
            if fix is not None and self._imu_fresh <= 1 and self.imu is not None:
                assert self.pose_time is not None
                age = self.imu.t - self.pose_time + (t - self._imu_step)
            chain = self.chain
            closed_for: PlatformReason | None = "device_restart" if self._timeline.pending else None
            try:
                valves = tuple(
                    bool(v)
                    for v in chain.update(
                        t, heading_ref, rate_ref, imu=imu, fix=fix, track=track,
                        closed_for=closed_for, fix_age=age,
                    )
                )  # fmt: skip
                if len(valves) != N_VALVES:
                    raise ValueError(f"the chain gave {len(valves)} valve states, not {N_VALVES}")
            except BaseException:
                self._send(encode_valves(self._next_seq(), 0), 1, CLOSED)
                raise
            # VALVES first: a write cut off after them sends no heartbeat to keep an older
            # command alive in the device (its failsafe closes the valves instead).
            seq = self._next_seq()
            self._send(encode_valves(seq, valves) + encode_heartbeat(seq, t), 2, valves)
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

    truth: Pose | None = None
    """A real platform's true pose is not known: its estimate is all there is."""

    @property
    def pose(self) -> Pose:
        """The chain's navigation estimate (what :meth:`step` returned last)."""
        return self.chain.estimate

    @property
    def valves(self) -> tuple[bool, ...]:
        """The eight valve states last commanded (all False after hold, close, a failure,
        or a write cut off: see :attr:`valves_confirmed`)."""
        return self._valves

    @property
    def counters(self) -> dict[Count, int]:
        """Decoder counters (frames_ok, bad_checksum, garbage_bytes, ...), the host's own
        (device_frames_off_timeline, device_restarts, write_timeouts, write_short, ...)
        and the chain's (closed steps per reason, fix_rejected, ...)."""
        return {**self._decoder.counters, **self._host, **self.chain.counters}

    def close(self) -> None:
        """Send all-valves-closed (best effort) and close the port. Idempotent.

        Frames still queued in the port's output go first (discarded): the all-closed
        is the last word on the line, not followed by older commands."""
        with self._lock:
            self._close_valves("close", flush=True)
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
    def _discard_output(self) -> None:
        """Drop what waits in the port's output queue (a port gone: PlatformError)."""
        try:
            self._serial.reset_output_buffer()
        except (serial.SerialException, OSError) as error:
            self._vanished(error)

    def _close_valves(self, why: str, flush: bool = False) -> None:
        """Hold the chain and send all-closed at once (best effort on a live port).

        ``flush``: discard the port's output queue first (and complete a frame it cut).
        """
        self.chain.hold()
        if self._failure is None:
            frame = encode_valves(self._next_seq(), 0)
            try:
                if flush:
                    self._serial.reset_output_buffer()
                    frame = _FILLER + frame
                self._send(frame, 1, CLOSED)
            except (PlatformError, serial.SerialException, OSError) as error:
                log.warning("%s: %s", why, error)

    def _check_open(self) -> None:
        if self._failure is not None:
            raise PlatformError(self._failure)

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) % _U32
        return seq

    def _read(self, now: float) -> None:
        self._read_frames(now)
        # Judged once everything waiting is read: a backlog comes in the device's order,
        # its POSE before the IMU samples that followed it.
        if (
            self._new_fix is not None
            and self.imu is not None
            and self.pose_time is not None
            and self.imu.t - self.pose_time > self.chain.fix_timeout
        ):
            self._host[Count.DEVICE_POSE_STALE] += 1  # older than the fix timeout: not a fix of now
            self._new_fix = None

    def _read_frames(self, now: float) -> None:
        """Read what the device sent (at most ``_MAX_READS`` chunks a step) and take each
        frame that lies on the device's timeline."""
        for _ in range(_MAX_READS):
            data = self._serial.read(_READ_CHUNK)
            if not data:
                return
            for message in self._decoder.feed(data):
                self._take(message, now)
            if len(data) < _READ_CHUNK:
                return

    def _take(self, message: object, now: float) -> None:
        """One decoded frame: a pose, an IMU sample or a status, if on the timeline."""
        if isinstance(message, DevicePose):
            if self._on_timeline("pose", message.t, now):
                self.device_pose = message.pose
                self.pose_time = message.t
                self._new_fix = message.pose
        elif isinstance(message, Imu):
            if self._on_timeline("imu", message.t, now):
                self.imu = message
                self._new_imu = ImuSample(message.gyro, message.ax, message.ay)
        elif isinstance(message, Status):
            fresh = not message.flags & FLAG_HEARTBEAT_SEEN
            if self._on_timeline("status", message.t, now, fresh=fresh):
                self.status = message
                if message.failsafe:
                    self._host[Count.DEVICE_FAILSAFE_REPORTS] += 1

    def _on_timeline(self, kind: Kind, t: float, now: float, fresh: bool = False) -> bool:
        """Whether to take a frame of ``kind`` at device time ``t``; counts the others."""
        verdict = self._timeline.judge(kind, t, now, fresh=fresh)
        if verdict == "not_newer":
            self._host[Count.DEVICE_FRAMES_NOT_NEWER] += 1  # replayed or reordered
            return False
        if verdict == "off_timeline":
            self._host[Count.DEVICE_FRAMES_OFF_TIMELINE] += 1  # an old frame, or a restart
            return False
        if verdict == "restarted":
            self._device_restarted(t)
        return True

    def _device_restarted(self, t: float) -> None:
        """The device's clock began again (a reset, a brownout), confirmed: nothing it
        measured before describes the platform now. The chain starts afresh (no fix until
        a POSE of the new timeline; position hold re-takes its point)."""
        self._host[Count.DEVICE_RESTARTS] += 1
        if _rate_limited(self._host[Count.DEVICE_RESTARTS]):
            log.warning(
                "serial device on %s restarted (its clock is at %.3f s; %d restarts so far): "
                "the estimate restarts, valves closed until its next POSE",
                self.port, t, self._host[Count.DEVICE_RESTARTS],
            )  # fmt: skip
        self.chain.restart()
        self.device_pose = self.pose_time = None
        self.imu = None
        self._new_fix = None
        self._new_imu = None

    def _send(self, frames: bytes, count: int, valves: tuple[bool, ...]) -> None:
        """Write a step's (or a hold's) frames; after a write cut off, close the valves."""
        if self._write(frames):
            self._host[Count.FRAMES_SENT] += count
            self._valves = valves
            self.valves_confirmed = True
            return
        # What reached the device is unknown (part of the frames; the rest may sit in the
        # port's queue and go out later): discard the queue, complete any frame cut off on
        # the line and command all-closed once. Without heartbeats the device's failsafe
        # covers a line that stays stuck.
        self._valves = CLOSED
        self.valves_confirmed = False
        self._discard_output()
        resent = self._write(_FILLER + encode_valves(self._next_seq(), 0))
        if resent:
            self._host[Count.FRAMES_SENT] += 1
        else:
            self._discard_output()
        self._cut_offs += 1
        failed = self._cut_offs
        if _rate_limited(failed):
            log.warning(
                "serial port %s: a write timed out or stopped short (%d so far); valves %s "
                "not confirmed; output queue discarded, all-closed %s",
                self.port, failed, _mask_text(valves), "sent" if resent else "not sent either",
            )  # fmt: skip

    def _write(self, data: bytes) -> bool:
        """Write ``data`` whole within the write timeout; False (counted) if not."""
        try:
            written = self._serial.write(data)
        except serial.SerialTimeoutException:  # raised after part, or even all, went out
            self._host[Count.WRITE_TIMEOUTS] += 1
            return False
        except (serial.SerialException, OSError) as error:
            self._vanished(error)
        if written is not None and written < len(data):  # an aborted write returns short
            self._host[Count.WRITE_SHORT] += 1
            return False
        return True

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

"""Serial protocol between the fedlab host and a platform's avionics: pure codec, no I/O.

Bytes go in (:meth:`FrameDecoder.feed`), messages come out; encoders turn
messages into frames. Nothing here opens a port or reads a clock: times travel
inside the messages. The full specification, with a byte-offset table per
message, is ``docs/serial-protocol.md``; the rules this module keeps are:

1. A frame is ``A5 5A | type u8 | length u8 | payload | crc u16``, little-endian.
   The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no
   final XOR) over ``type``, ``length`` and ``payload``; the sync bytes are not in it.
2. ``length`` is at most :data:`MAX_PAYLOAD` (64); a header claiming more is
   rejected at once (``oversize``), without waiting for bytes that may never come.
3. Bytes before a sync pattern are skipped and counted (``garbage_bytes``).
4. A frame whose CRC does not match is dropped and counted (``bad_checksum``);
   the decoder then resumes its search one byte after the rejected sync, so a
   good frame hidden behind a corrupted length byte is still found.
5. A frame with a good CRC is consumed whole, even when it is not accepted:
   a type this decoder does not accept (``unknown_type``), a known type with the
   wrong payload length (``bad_length``) or a non-finite float (``bad_value``).
6. Decoding never raises, whatever the input. Every byte fed ends up in exactly
   one place: ``bytes_in == frame_bytes + garbage_bytes + pending``.

Message types
-------------
======  =========  =============  ======  ===========================================
type    name       direction      length  payload (see docs/serial-protocol.md)
======  =========  =============  ======  ===========================================
0x01    IMU        device -> host 20      t f64, gyro f32, ax f32, ay f32
0x02    POSE       device -> host 32      t f64, x y heading vx vy omega f32
0x03    STATUS     device -> host 36      t f64, valves, flags, timeout, counters
0x10    VALVES     host -> device 5       seq u32, mask u8 (bit i = valve i open)
0x11    HEARTBEAT  host -> device 12      seq u32, host time f64
======  =========  =============  ======  ===========================================
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

from federation.core.counters import Count
from federation.core.wire import Pose

__all__ = [
    "ALL_TYPES",
    "DEVICE_TO_HOST",
    "FLAG_FAILSAFE",
    "FLAG_HEARTBEAT_SEEN",
    "HOST_TO_DEVICE",
    "MAX_PAYLOAD",
    "N_VALVES",
    "OVERHEAD",
    "PAYLOAD_SIZES",
    "SYNC",
    "TYPE_HEARTBEAT",
    "TYPE_IMU",
    "TYPE_POSE",
    "TYPE_STATUS",
    "TYPE_VALVES",
    "DevicePose",
    "FrameDecoder",
    "Heartbeat",
    "Imu",
    "Message",
    "Status",
    "Valves",
    "crc16_ccitt",
    "encode",
    "encode_frame",
    "encode_heartbeat",
    "encode_imu",
    "encode_pose",
    "encode_status",
    "encode_valves",
    "mask_to_valves",
    "valves_to_mask",
]

SYNC = b"\xa5\x5a"
"""Two sync bytes that open every frame."""
MAX_PAYLOAD = 64
"""Longest payload a frame may carry, bytes."""
N_VALVES = 8
"""Solenoid valves (thrusters) on the platform."""

TYPE_IMU = 0x01
TYPE_POSE = 0x02
TYPE_STATUS = 0x03
TYPE_VALVES = 0x10
TYPE_HEARTBEAT = 0x11

FLAG_FAILSAFE = 0x01
"""STATUS flag: the device holds every valve closed because heartbeats stopped."""
FLAG_HEARTBEAT_SEEN = 0x02
"""STATUS flag: at least one heartbeat has arrived since the device started."""

_HEADER = struct.Struct("<2sBB")  # sync, type, length
_CRC = struct.Struct("<H")
OVERHEAD = _HEADER.size + _CRC.size
"""Bytes a frame adds to its payload: 2 sync, type, length, 2 CRC."""

_IMU = struct.Struct("<dfff")
_POSE = struct.Struct("<d6f")
_STATUS = struct.Struct("<dBBHIIIIII")
_VALVES = struct.Struct("<IB")
_HEARTBEAT = struct.Struct("<Id")

PAYLOAD_SIZES = {
    TYPE_IMU: _IMU.size,  # 20
    TYPE_POSE: _POSE.size,  # 32
    TYPE_STATUS: _STATUS.size,  # 36
    TYPE_VALVES: _VALVES.size,  # 5
    TYPE_HEARTBEAT: _HEARTBEAT.size,  # 12
}
"""Payload length of each message type, bytes."""

DEVICE_TO_HOST = frozenset({TYPE_IMU, TYPE_POSE, TYPE_STATUS})
HOST_TO_DEVICE = frozenset({TYPE_VALVES, TYPE_HEARTBEAT})
ALL_TYPES = DEVICE_TO_HOST | HOST_TO_DEVICE

_U32 = 1 << 32


# -- messages --------------------------------------------------------------------
class Imu(NamedTuple):
    """IMU sample: device time (s), yaw rate (rad/s), body accelerations (m/s^2)."""

    t: float
    gyro: float
    ax: float
    ay: float


class DevicePose(NamedTuple):
    """The device's own navigation estimate at device time ``t`` (s)."""

    t: float
    pose: Pose


class Status(NamedTuple):
    """Device health, in the device's units.

    ``valves`` is the bitmask actually applied (bit ``i`` = valve ``i`` open),
    which is 0 whenever the failsafe holds. Counters are the device's receive
    counters for host frames, modulo 2**32.
    """

    t: float
    valves: int
    flags: int
    heartbeat_timeout_ms: int
    valves_seq: int
    heartbeat_seq: int
    frames_ok: int
    bad_checksum: int
    garbage_bytes: int
    failsafe_trips: int

    @property
    def failsafe(self) -> bool:
        """True if the device holds every valve closed for lack of heartbeats."""
        return bool(self.flags & FLAG_FAILSAFE)


class Valves(NamedTuple):
    """Host command: ``mask`` bit ``i`` opens valve ``i``; ``seq`` counts commands mod 2**32."""

    seq: int
    mask: int


class Heartbeat(NamedTuple):
    """Host keep-alive: ``seq`` mod 2**32 and the host's time (s)."""

    seq: int
    host_time: float


Message = Imu | DevicePose | Status | Valves | Heartbeat


# -- CRC -------------------------------------------------------------------------
def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_TABLE = _crc_table()


def crc16_ccitt(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, MSB first, no final XOR.

    Its check value, the CRC of ``b"123456789"``, is ``0x29B1``.
    """
    table = _TABLE
    for byte in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


# -- encoders --------------------------------------------------------------------
def encode_frame(msg_type: int, payload: bytes) -> bytes:
    """Wrap ``payload`` in a frame: sync, type, length, payload, CRC (little-endian).

    Raises
    ------
    ValueError
        If ``msg_type`` is not a byte or ``payload`` is longer than :data:`MAX_PAYLOAD`.
    """
    if not 0 <= msg_type <= 0xFF:
        raise ValueError(f"message type must be 0-255, not {msg_type!r}")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((msg_type, len(payload))) + payload
    return SYNC + body + _CRC.pack(crc16_ccitt(body))


def _finite(values: Iterable[float], what: str) -> None:
    for index, value in enumerate(values):
        if not math.isfinite(value):
            raise ValueError(f"{what}: field {index} is {value!r}, not a finite number")


def _u32(value: int, what: str) -> int:
    if not 0 <= value < _U32:
        raise ValueError(f"{what} must be 0 <= n < 2**32, not {value!r}")
    return value


def encode_imu(t: float, gyro: float, ax: float, ay: float) -> bytes:
    """IMU frame: device time (s, f64), gyro (rad/s), ax and ay (m/s^2) as f32."""
    _finite((t, gyro, ax, ay), "IMU")
    return encode_frame(TYPE_IMU, _IMU.pack(t, gyro, ax, ay))


def encode_pose(t: float, pose: Pose) -> bytes:
    """POSE frame: device time (s, f64), then x, y, heading, vx, vy, omega as f32."""
    _finite((t, *pose), "POSE")
    return encode_frame(TYPE_POSE, _POSE.pack(t, *pose))


def encode_status(status: Status) -> bytes:
    """STATUS frame; counters are taken modulo 2**32, the timeout saturates at 65535 ms."""
    _finite((status.t,), "STATUS")
    if not 0 <= status.valves <= 0xFF or not 0 <= status.flags <= 0xFF:
        raise ValueError(f"STATUS: valves and flags must be bytes: {status!r}")
    payload = _STATUS.pack(
        status.t,
        status.valves,
        status.flags,
        min(max(status.heartbeat_timeout_ms, 0), 0xFFFF),
        *(n % _U32 for n in status[4:]),
    )
    return encode_frame(TYPE_STATUS, payload)


def encode_valves(seq: int, valves: int | Sequence[bool]) -> bytes:
    """VALVES frame: ``seq`` (u32) and the eight valve states, as a mask or a sequence."""
    mask = valves if isinstance(valves, int) else valves_to_mask(valves)
    if not 0 <= mask <= 0xFF:
        raise ValueError(f"valve mask must be 0-255, not {mask!r}")
    return encode_frame(TYPE_VALVES, _VALVES.pack(_u32(seq, "VALVES seq"), mask))


def encode_heartbeat(seq: int, host_time: float) -> bytes:
    """HEARTBEAT frame: ``seq`` (u32) and the host's time (s, f64)."""
    _finite((host_time,), "HEARTBEAT")
    return encode_frame(TYPE_HEARTBEAT, _HEARTBEAT.pack(_u32(seq, "HEARTBEAT seq"), host_time))


def encode(message: Message) -> bytes:
    """Frame for any message."""
    if isinstance(message, Imu):
        return encode_imu(*message)
    if isinstance(message, DevicePose):
        return encode_pose(*message)
    if isinstance(message, Status):
        return encode_status(message)
    if isinstance(message, Valves):
        return encode_valves(*message)
    return encode_heartbeat(*message)


def valves_to_mask(valves: Sequence[bool]) -> int:
    """Bitmask of eight valve states: bit ``i`` set if valve ``i`` is open."""
    if len(valves) != N_VALVES:
        raise ValueError(f"expected {N_VALVES} valve states, got {len(valves)}")
    return sum(1 << i for i, on in enumerate(valves) if on)


def mask_to_valves(mask: int) -> tuple[bool, ...]:
    """Eight valve states from a bitmask (bit ``i`` = valve ``i`` open)."""
    return tuple(bool(mask >> i & 1) for i in range(N_VALVES))


# -- decoder ---------------------------------------------------------------------
def _decode_imu(p: bytes) -> Imu:
    return Imu(*_IMU.unpack(p))


def _decode_pose(p: bytes) -> DevicePose:
    t, *rest = _POSE.unpack(p)
    return DevicePose(t, Pose(*rest))


def _decode_status(p: bytes) -> Status:
    return Status(*_STATUS.unpack(p))


def _decode_valves(p: bytes) -> Valves:
    return Valves(*_VALVES.unpack(p))


def _decode_heartbeat(p: bytes) -> Heartbeat:
    return Heartbeat(*_HEARTBEAT.unpack(p))


_DECODERS: dict[int, Callable[[bytes], Message]] = {
    TYPE_IMU: _decode_imu,
    TYPE_POSE: _decode_pose,
    TYPE_STATUS: _decode_status,
    TYPE_VALVES: _decode_valves,
    TYPE_HEARTBEAT: _decode_heartbeat,
}


def _all_finite(message: Message) -> bool:
    values: list[float] = [message.t] if isinstance(message, Imu | DevicePose | Status) else []
    if isinstance(message, Imu):
        values += message[1:]
    elif isinstance(message, DevicePose):
        values += message.pose
    elif isinstance(message, Heartbeat):
        values.append(message.host_time)
    return all(math.isfinite(v) for v in values)


class FrameDecoder:
    """Incremental decoder: :meth:`feed` bytes as they arrive, get whole messages back.

    Parameters
    ----------
    accept : Iterable[int]
        Message types to decode; frames of other types (with a good CRC) are
        consumed and counted as ``unknown_type``. The host passes
        :data:`DEVICE_TO_HOST`, the device :data:`HOST_TO_DEVICE`.

    Attributes
    ----------
    frames_ok, bad_checksum, garbage_bytes, oversize, unknown_type, bad_length, bad_value : int
        Counters, see the module docstring. ``frame_bytes`` counts the bytes of
        frames with a good CRC (accepted or not) and ``bytes_in`` every byte fed.
    """

    COUNTERS = (
        Count.FRAMES_OK,
        Count.BAD_CHECKSUM,
        Count.GARBAGE_BYTES,
        Count.OVERSIZE,
        Count.UNKNOWN_TYPE,
        Count.BAD_LENGTH,
        Count.BAD_VALUE,
        Count.FRAME_BYTES,
        Count.BYTES_IN,
    )
    """Every counter, each an attribute of its own name."""

    def __init__(self, accept: Iterable[int] = ALL_TYPES):
        self.accept = frozenset(accept)
        self._buf = bytearray()
        self.frames_ok = 0
        self.bad_checksum = 0
        self.garbage_bytes = 0
        self.oversize = 0
        self.unknown_type = 0
        self.bad_length = 0
        self.bad_value = 0
        self.frame_bytes = 0
        self.bytes_in = 0

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame (at most ``MAX_PAYLOAD + 6``)."""
        return len(self._buf)

    @property
    def counters(self) -> dict[Count, int]:
        """A snapshot of every counter by name."""
        return {count: getattr(self, count.value) for count in self.COUNTERS}

    def feed(self, data: bytes | bytearray | memoryview) -> list[Message]:
        """Add received bytes; return the messages completed by them, in order. Never raises."""
        self.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list[Message] = []
        while True:
            start = buf.find(SYNC)
            if start < 0:
                # Keep a trailing first sync byte: its partner may come in the next read.
                keep = 1 if buf[-1:] == SYNC[:1] else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < _HEADER.size:
                break
            msg_type, length = buf[2], buf[3]
            if length > MAX_PAYLOAD:
                self.oversize += 1
                self._reject_sync()
                continue
            end = _HEADER.size + length
            if len(buf) < end + _CRC.size:
                break
            (crc,) = _CRC.unpack_from(buf, end)
            if crc != crc16_ccitt(buf[2:end]):
                self.bad_checksum += 1
                self._reject_sync()
                continue
            payload = bytes(buf[_HEADER.size : end])
            del buf[: end + _CRC.size]
            self.frame_bytes += end + _CRC.size
            message = self._message(msg_type, payload)
            if message is not None:
                self.frames_ok += 1
                out.append(message)
        return out

    def _reject_sync(self) -> None:
        # Drop the first sync byte only; the search resumes right behind it.
        self.garbage_bytes += 1
        del self._buf[:1]

    def _message(self, msg_type: int, payload: bytes) -> Message | None:
        if msg_type not in self.accept or msg_type not in _DECODERS:
            self.unknown_type += 1
            return None
        if len(payload) != PAYLOAD_SIZES[msg_type]:
            self.bad_length += 1
            return None
        message = _DECODERS[msg_type](payload)
        if not _all_finite(message):
            self.bad_value += 1
            return None
        return message

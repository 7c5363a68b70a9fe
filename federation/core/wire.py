"""Wire codecs: the paper's packets (section 3.2), byte for byte.

All fields are IEEE-754 float64, little-endian. Times are seconds on the
*sender's* execution clock; positions in metres, angles in radians, in the
federation's common frame.

=========  ======  =====  ==========================================
message    offset  field  meaning
=========  ======  =====  ==========================================
request    0       t1     client clock when the request is sent
reply      0       t1     echoed from the request
reply      8       t2     server clock when the request arrived
reply      16-56   pose   x, y, heading, vx, vy, omega
pose       0       t      sender's execution clock at the pose
pose       8-48    pose   x, y, heading, vx, vy, omega
=========  ======  =====  ==========================================

Sizes: request 8 bytes, reply 64 bytes, pose sample 56 bytes. Decoders accept
exactly these sizes and finite values only; anything else raises
:class:`DecodeError` (a ``ValueError``) saying what was wrong.

A pose sample's Zenoh *attachment* (24 bytes, little-endian; the payload stays the
paper's 56 bytes, so a receiver that ignores attachments loses nothing) carries the
sender's reference stamp: the pose's ``t`` on reference (simulation) time, so that
a receiver places it without syncing with the sender.

=========  ======  ========  ==============================================
field      offset  type      meaning
=========  ======  ========  ==============================================
version    0       u8        1
flags      1       u8        bit 0: ``t_ref`` and ``bound`` are valid (sender
                             synchronized with its reference); others 0
reserved   2       u16       0
ref_id     4       u32       CRC-32 of the reference agent's ``lab/name``
t_ref      8       f64       reference time (s) of the pose's ``t``
bound      16      f64       error bound of ``t_ref`` (s, >= 0): the sender's
                             one-way delay to the reference plus its
                             estimate's own bound; 0 on it
=========  ======  ========  ==============================================

The sample's Zenoh source info (session id, sequence number) names its publisher
(the contest watch); it is Zenoh metadata, not part of the attachment.
"""

from __future__ import annotations

import math
import struct
import zlib
from typing import NamedTuple

__all__ = [
    "POSE_SIZE",
    "REPLY_SIZE",
    "REQUEST_SIZE",
    "STAMP_SIZE",
    "STAMP_VERSION",
    "DecodeError",
    "Pose",
    "PoseSample",
    "RefStamp",
    "SyncReply",
    "decode_pose",
    "decode_reply",
    "decode_request",
    "decode_stamp",
    "encode_pose",
    "encode_reply",
    "encode_request",
    "encode_stamp",
    "reference_id",
]

_REQUEST = struct.Struct("<d")
_REPLY = struct.Struct("<8d")
_POSE = struct.Struct("<7d")
REQUEST_SIZE = _REQUEST.size  # 8
REPLY_SIZE = _REPLY.size  # 64
POSE_SIZE = _POSE.size  # 56
_STAMP = struct.Struct("<BBHIdd")
STAMP_SIZE = _STAMP.size  # 24
STAMP_VERSION = 1
_STAMPED = 0x01


class DecodeError(ValueError):
    """A payload that is not a well-formed fedlab message."""


class Pose(NamedTuple):
    """Planar pose and its rates (m, m, rad, m/s, m/s, rad/s)."""

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    omega: float = 0.0


class SyncReply(NamedTuple):
    t1: float
    t2: float
    pose: Pose


class PoseSample(NamedTuple):
    t: float
    pose: Pose


def _unpack(
    codec: struct.Struct, payload: bytes | bytearray | memoryview, what: str
) -> tuple[float, ...]:
    if len(payload) != codec.size:
        raise DecodeError(f"{what}: expected {codec.size} bytes, got {len(payload)}")
    values: tuple[float, ...] = codec.unpack(payload)
    _check_finite(values, what, DecodeError)
    return values


def _check_finite(
    values: tuple[float, ...], what: str, error: type[ValueError] = ValueError
) -> None:
    if math.isfinite(sum(values)):
        return  # the sum of finite numbers is finite but for an overflow: one C loop
    for index, value in enumerate(values):
        if not math.isfinite(value):
            raise error(f"{what}: field {index} is {value!r}, not a finite number")


def encode_request(t1: float) -> bytes:
    """Request (8 bytes): ``t1``."""
    _check_finite((t1,), "request")
    return _REQUEST.pack(t1)


def decode_request(payload: bytes | bytearray | memoryview) -> float:
    """Return ``t1`` from a request."""
    return _unpack(_REQUEST, payload, "sync request")[0]


def encode_reply(t1: float, t2: float, pose: Pose) -> bytes:
    """Reply (64 bytes): ``t1`` echoed, ``t2``, then the pose."""
    values = (t1, t2, *pose)
    _check_finite(values, "reply")
    return _REPLY.pack(*values)


def decode_reply(payload: bytes | bytearray | memoryview) -> SyncReply:
    v = _unpack(_REPLY, payload, "sync reply")
    return SyncReply(v[0], v[1], Pose(*v[2:]))


def encode_pose(t: float, pose: Pose) -> bytes:
    """Pose sample (56 bytes): sender's execution time, then the pose."""
    values = (t, *pose)
    _check_finite(values, "pose sample")
    return _POSE.pack(*values)


def decode_pose(payload: bytes | bytearray | memoryview) -> PoseSample:
    v = _unpack(_POSE, payload, "pose sample")
    return PoseSample(v[0], Pose(*v[1:]))


class RefStamp(NamedTuple):
    """A pose sample's reference stamp (its attachment): ``t_ref`` and ``bound`` are
    None when the sender was not yet synchronized with its reference."""

    ref_id: int
    t_ref: float | None
    bound: float | None


def reference_id(agent: str) -> int:
    """The ``ref_id`` of a reference agent ``"lab/name"``: CRC-32 of its UTF-8 name."""
    return zlib.crc32(agent.encode())


def encode_stamp(ref_id: int, t_ref: float | None, bound: float | None) -> bytes:
    """A pose sample's attachment (24 bytes); ``t_ref`` None: not yet synchronized."""
    if not 0 <= ref_id < 2**32:
        raise ValueError(f"reference stamp: ref_id {ref_id!r} is not a 32-bit unsigned integer")
    if t_ref is None or bound is None:
        return _STAMP.pack(STAMP_VERSION, 0, 0, ref_id, 0.0, 0.0)
    _check_finite((t_ref, bound), "reference stamp")
    if bound < 0:
        raise ValueError(f"reference stamp: bound {bound!r} is negative")
    return _STAMP.pack(STAMP_VERSION, _STAMPED, 0, ref_id, t_ref, bound)


def decode_stamp(attachment: bytes | bytearray | memoryview) -> RefStamp:
    """Read a pose sample's attachment; :class:`DecodeError` if it is not one."""
    if len(attachment) != STAMP_SIZE:
        raise DecodeError(f"reference stamp: expected {STAMP_SIZE} bytes, got {len(attachment)}")
    version, flags, reserved, ref_id, t_ref, bound = _STAMP.unpack(attachment)
    if version != STAMP_VERSION:
        raise DecodeError(f"reference stamp: version {version}, this reader knows {STAMP_VERSION}")
    if flags & ~_STAMPED or reserved:
        raise DecodeError(f"reference stamp: unknown flags {flags:#04x} or reserved {reserved}")
    if not flags & _STAMPED:
        return RefStamp(ref_id, None, None)
    _check_finite((t_ref, bound), "reference stamp", DecodeError)
    if bound < 0:
        raise DecodeError(f"reference stamp: bound {bound!r} is negative")
    return RefStamp(ref_id, t_ref, bound)

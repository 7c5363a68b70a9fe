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
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple

__all__ = [
    "POSE_SIZE",
    "REPLY_SIZE",
    "REQUEST_SIZE",
    "DecodeError",
    "Pose",
    "PoseSample",
    "SyncReply",
    "decode_pose",
    "decode_reply",
    "decode_request",
    "encode_pose",
    "encode_reply",
    "encode_request",
]

_REQUEST = struct.Struct("<d")
_REPLY = struct.Struct("<8d")
_POSE = struct.Struct("<7d")
REQUEST_SIZE = _REQUEST.size  # 8
REPLY_SIZE = _REPLY.size  # 64
POSE_SIZE = _POSE.size  # 56


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

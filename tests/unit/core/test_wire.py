"""Byte-for-byte tests of the paper's packets (federation/wire.py).

Expected bytes are built independently of the module under test: with ``struct``
format strings written out here, or as literal hex.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from federation.core import wire
from federation.core.wire import (
    POSE_SIZE,
    REPLY_SIZE,
    REQUEST_SIZE,
    DecodeError,
    Pose,
    PoseSample,
    SyncReply,
    decode_pose,
    decode_reply,
    decode_request,
    encode_pose,
    encode_reply,
    encode_request,
)

finite = st.floats(allow_nan=False, allow_infinity=False)
poses = st.builds(Pose, finite, finite, finite, finite, finite, finite)
NON_FINITE = [math.nan, math.inf, -math.inf]
NON_FINITE_IDS = ["nan", "+inf", "-inf"]
Decoder = Callable[[bytes], Any]
# The reply and the pose sample as flat lists of float64 fields: each field in turn.
FIELDS = {"reply": 8, "pose": 7}
EVERY_FIELD = [pytest.param(k, i, id=f"{k}-{i}") for k, n in FIELDS.items() for i in range(n)]
DECODE: dict[str, tuple[Decoder, str]] = {
    "reply": (decode_reply, "sync reply"),
    "pose": (decode_pose, "pose sample"),
}
ENCODE: dict[str, Callable[[list[float]], bytes]] = {
    "reply": lambda v: encode_reply(v[0], v[1], Pose(*v[2:])),
    "pose": lambda v: encode_pose(v[0], Pose(*v[1:])),
}


def le_doubles(*values: float) -> bytes:
    """Little-endian float64s, packed one by one (independent of wire's Structs)."""
    return b"".join(struct.pack("<d", v) for v in values)


# --------------------------------------------------------------------- sizes


def test_sizes_are_the_papers() -> None:
    assert REQUEST_SIZE == 8
    assert REPLY_SIZE == 64
    assert POSE_SIZE == 56


def test_encoded_lengths() -> None:
    assert len(encode_request(0.0)) == 8
    assert len(encode_reply(0.0, 0.0, Pose())) == 64
    assert len(encode_pose(0.0, Pose())) == 56


def test_encoders_return_bytes() -> None:
    assert type(encode_request(1.0)) is bytes
    assert type(encode_reply(1.0, 2.0, Pose())) is bytes
    assert type(encode_pose(1.0, Pose())) is bytes


# ------------------------------------------------------------ literal bytes


def test_request_literal_hex() -> None:
    assert encode_request(1.0) == bytes.fromhex("000000000000f03f")
    assert encode_request(-2.0) == bytes.fromhex("00000000000000c0")
    assert encode_request(0.0) == bytes(8)


def test_request_is_little_endian_not_big() -> None:
    payload = encode_request(26.42)
    assert payload == struct.pack("<d", 26.42)
    assert payload != struct.pack(">d", 26.42)


def test_decode_request_literal_hex() -> None:
    assert decode_request(bytes.fromhex("000000000000f03f")) == 1.0
    assert decode_request(bytes.fromhex("0000000000000840")) == 3.0


def test_reply_layout_field_by_field() -> None:
    pose = Pose(x=1.5, y=-2.25, heading=0.785, vx=0.01, vy=-0.02, omega=0.003)
    payload = encode_reply(100.125, 126.545, pose)
    assert payload == le_doubles(100.125, 126.545, 1.5, -2.25, 0.785, 0.01, -0.02, 0.003)
    # Offsets given in the module's table: t1 at 0, t2 at 8, pose at 16..56.
    assert struct.unpack_from("<d", payload, 0)[0] == 100.125
    assert struct.unpack_from("<d", payload, 8)[0] == 126.545
    assert struct.unpack_from("<d", payload, 16)[0] == 1.5  # x
    assert struct.unpack_from("<d", payload, 24)[0] == -2.25  # y
    assert struct.unpack_from("<d", payload, 32)[0] == 0.785  # heading
    assert struct.unpack_from("<d", payload, 40)[0] == 0.01  # vx
    assert struct.unpack_from("<d", payload, 48)[0] == -0.02  # vy
    assert struct.unpack_from("<d", payload, 56)[0] == 0.003  # omega


def test_reply_literal_hex() -> None:
    payload = encode_reply(1.0, 2.0, Pose(heading=-2.0))
    expected = (
        "000000000000f03f"  # t1 = 1.0
        "0000000000000040"  # t2 = 2.0
        "0000000000000000"  # x
        "0000000000000000"  # y
        "00000000000000c0"  # heading = -2.0
        "0000000000000000"  # vx
        "0000000000000000"  # vy
        "0000000000000000"  # omega
    )
    assert payload == bytes.fromhex(expected)


def test_decode_reply_from_hand_built_bytes() -> None:
    payload = le_doubles(3.0, 29.42, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    reply = decode_reply(payload)
    assert isinstance(reply, SyncReply)
    assert reply.t1 == 3.0
    assert reply.t2 == 29.42
    assert isinstance(reply.pose, Pose)
    assert reply.pose == Pose(x=0.1, y=0.2, heading=0.3, vx=0.4, vy=0.5, omega=0.6)
    assert reply.pose.omega == 0.6
    assert reply.pose.vx == 0.4


def test_pose_layout_field_by_field() -> None:
    pose = Pose(x=-1.0, y=2.5, heading=3.0, vx=-0.125, vy=0.0625, omega=-4.0)
    payload = encode_pose(42.5, pose)
    assert payload == le_doubles(42.5, -1.0, 2.5, 3.0, -0.125, 0.0625, -4.0)
    assert struct.unpack_from("<d", payload, 0)[0] == 42.5  # t
    assert struct.unpack_from("<d", payload, 24)[0] == 3.0  # heading
    assert struct.unpack_from("<d", payload, 48)[0] == -4.0  # omega


def test_pose_literal_hex() -> None:
    payload = encode_pose(1.0, Pose(omega=1.0))
    expected = "000000000000f03f" + "00" * 40 + "000000000000f03f"
    assert payload == bytes.fromhex(expected)


def test_decode_pose_from_hand_built_bytes() -> None:
    sample = decode_pose(le_doubles(7.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0))
    assert isinstance(sample, PoseSample)
    assert sample.t == 7.0
    assert sample.pose == Pose(1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert sample.pose.x == 1.0
    assert sample.pose.heading == 3.0


def test_pose_defaults_are_zero() -> None:
    assert Pose() == (0.0,) * 6
    assert encode_pose(0.0, Pose()) == bytes(56)


@pytest.mark.parametrize("kind", [bytes, bytearray, memoryview])
def test_decoders_accept_bytes_like(kind: type) -> None:
    assert decode_request(kind(le_doubles(5.0))) == 5.0
    assert decode_reply(kind(le_doubles(*range(8)))).t2 == 1.0
    assert decode_pose(kind(le_doubles(*range(7)))).pose.omega == 6.0


def test_negative_zero_survives() -> None:
    payload = encode_request(-0.0)
    assert payload == bytes.fromhex("0000000000000080")
    assert math.copysign(1.0, decode_request(payload)) == -1.0


def test_extreme_finite_values() -> None:
    tiny = 5e-324  # smallest subnormal
    huge = 1.7976931348623157e308
    assert decode_request(encode_request(tiny)) == tiny
    assert decode_request(encode_request(-huge)) == -huge
    assert encode_request(huge) == bytes.fromhex("ffffffffffffef7f")


# -------------------------------------------------------------- round trips


@given(finite)
def test_request_round_trip(t1: float) -> None:
    payload = encode_request(t1)
    assert payload == struct.pack("<d", t1)
    assert decode_request(payload) == t1


@given(finite, finite, poses)
def test_reply_round_trip(t1: float, t2: float, pose: Pose) -> None:
    payload = encode_reply(t1, t2, pose)
    assert payload == le_doubles(t1, t2, *pose)
    assert decode_reply(payload) == SyncReply(t1, t2, pose)


@given(finite, poses)
def test_pose_round_trip(t: float, pose: Pose) -> None:
    payload = encode_pose(t, pose)
    assert payload == le_doubles(t, *pose)
    assert decode_pose(payload) == PoseSample(t, pose)


@given(st.lists(finite, min_size=8, max_size=8))
def test_reply_decode_encode_is_identity_on_bytes(values: list[float]) -> None:
    payload = le_doubles(*values)
    reply = decode_reply(payload)
    assert encode_reply(reply.t1, reply.t2, reply.pose) == payload


# ------------------------------------------------------------ wrong sizes

DECODERS = [
    pytest.param(decode_request, 8, "sync request", id="request"),
    pytest.param(decode_reply, 64, "sync reply", id="reply"),
    pytest.param(decode_pose, 56, "pose sample", id="pose"),
]


@pytest.mark.parametrize(("decode", "size", "what"), DECODERS)
@pytest.mark.parametrize("length", [0, 7, 9, 55, 57, 63, 65, 128])
def test_wrong_size_rejected(decode: Decoder, size: int, what: str, length: int) -> None:
    with pytest.raises(DecodeError) as info:
        decode(bytes(length))
    message = str(info.value)
    assert what in message
    assert f"expected {size} bytes" in message
    assert f"got {length}" in message


@pytest.mark.parametrize(("decode", "size", "what"), DECODERS)
def test_exact_size_of_zeros_accepted(decode: Decoder, size: int, what: str) -> None:
    decode(bytes(size))  # must not raise


def test_request_bytes_not_accepted_as_reply_and_vice_versa() -> None:
    with pytest.raises(DecodeError):
        decode_reply(encode_request(1.0))
    with pytest.raises(DecodeError):
        decode_request(encode_reply(1.0, 2.0, Pose()))
    with pytest.raises(DecodeError):
        decode_pose(encode_reply(1.0, 2.0, Pose()))
    with pytest.raises(DecodeError):
        decode_reply(encode_pose(1.0, Pose()))


def test_decode_error_is_value_error() -> None:
    assert issubclass(DecodeError, ValueError)


# ------------------------------------------------------- non-finite values


@pytest.mark.parametrize("bad", NON_FINITE, ids=NON_FINITE_IDS)
def test_request_non_finite_rejected(bad: float) -> None:
    with pytest.raises(DecodeError) as info:
        decode_request(struct.pack("<d", bad))
    message = str(info.value)
    assert "sync request" in message
    assert "field 0" in message
    assert repr(bad) in message
    assert "not a finite number" in message


@pytest.mark.parametrize("bad", NON_FINITE, ids=NON_FINITE_IDS)
@pytest.mark.parametrize(("kind", "position"), EVERY_FIELD)
def test_non_finite_rejected_in_every_field(kind: str, position: int, bad: float) -> None:
    decode, what = DECODE[kind]
    values = [1.0] * FIELDS[kind]
    values[position] = bad
    with pytest.raises(DecodeError) as info:
        decode(le_doubles(*values))
    message = str(info.value)
    assert what in message
    assert f"field {position}" in message
    assert repr(bad) in message


def test_nan_with_payload_bits_rejected() -> None:
    # A negative quiet NaN with a non-default payload: still NaN, still rejected.
    assert math.isnan(struct.unpack("<d", bytes.fromhex("010000000000f8ff"))[0])
    with pytest.raises(DecodeError):
        decode_request(bytes.fromhex("010000000000f8ff"))
    # A signalling NaN bit pattern.
    assert math.isnan(struct.unpack("<d", bytes.fromhex("010000000000f07f"))[0])
    with pytest.raises(DecodeError):
        decode_request(bytes.fromhex("010000000000f07f"))


def test_first_bad_field_is_reported() -> None:
    values = [1.0, 2.0, math.inf, 4.0, math.nan, 6.0, 7.0, 8.0]
    with pytest.raises(DecodeError, match="field 2"):
        decode_reply(le_doubles(*values))


# ------------------------------------------------------------------ fuzzing


@pytest.mark.parametrize(
    "decode", [decode_request, decode_reply, decode_pose], ids=["request", "reply", "pose"]
)
@given(payload=st.binary(max_size=80))
def test_decoders_fuzz_only_decode_error(decode: Decoder, payload: bytes) -> None:
    try:
        result = decode(payload)
    except DecodeError:
        return
    except Exception as error:  # pragma: no cover - this is the failure being looked for
        pytest.fail(f"{decode.__name__} raised {type(error).__name__}: {error}")
    # Whatever decoded is made of finite floats and re-encodes to the same bytes.
    if decode is decode_request:
        assert math.isfinite(result)
        assert encode_request(result) == payload
    elif decode is decode_reply:
        assert encode_reply(result.t1, result.t2, result.pose) == payload
    else:
        assert encode_pose(result.t, result.pose) == payload


@pytest.mark.parametrize(
    ("decode", "size"),
    [(decode_request, 8), (decode_reply, 64), (decode_pose, 56)],
    ids=["request", "reply", "pose"],
)
@given(data=st.data())
def test_decoders_fuzz_right_size(decode: Decoder, size: int, data: st.DataObject) -> None:
    payload = data.draw(st.binary(min_size=size, max_size=size))
    try:
        decode(payload)
    except DecodeError as error:
        assert "not a finite number" in str(error)


# ---------------------------------------------------------------- encoders


@pytest.mark.parametrize("bad", NON_FINITE, ids=NON_FINITE_IDS)
def test_encode_request_refuses_non_finite(bad: float) -> None:
    with pytest.raises(ValueError, match="not a finite number"):
        encode_request(bad)


@pytest.mark.parametrize("bad", NON_FINITE, ids=NON_FINITE_IDS)
@pytest.mark.parametrize(("kind", "position"), EVERY_FIELD)
def test_encode_refuses_non_finite_in_every_field(kind: str, position: int, bad: float) -> None:
    values = [0.5] * FIELDS[kind]
    values[position] = bad
    with pytest.raises(ValueError, match=f"field {position}"):
        ENCODE[kind](values)


def test_all_exports_exist() -> None:
    for name in wire.__all__:
        assert hasattr(wire, name), name


# -- the pose sample's reference stamp (its attachment) ------------------------------
def test_stamp_bytes_are_the_documented_layout() -> None:
    ref_id = wire.reference_id("kiruna/knatte")
    encoded = wire.encode_stamp(ref_id, 12.5, 0.00025)
    assert len(encoded) == wire.STAMP_SIZE == 24
    assert encoded == bytes([1, 1, 0, 0]) + struct.pack("<I", ref_id) + struct.pack(
        "<dd", 12.5, 0.00025
    )
    assert wire.decode_stamp(encoded) == wire.RefStamp(ref_id, 12.5, 0.00025)


def test_stamp_literal_hex() -> None:
    # version 1, flags 1, reserved 0, ref_id 0x04030201, t_ref 1.0, bound 0.5
    literal = bytes.fromhex("0101000001020304000000000000f03f000000000000e03f")
    assert wire.decode_stamp(literal) == wire.RefStamp(0x04030201, 1.0, 0.5)
    assert wire.encode_stamp(0x04030201, 1.0, 0.5) == literal


def test_reference_id_is_crc32_of_the_name() -> None:
    import zlib

    assert wire.reference_id("lab0/a0") == zlib.crc32(b"lab0/a0")
    assert wire.reference_id("lab0/a0") != wire.reference_id("lab0/a1")


def test_unsynchronized_sender_stamps_without_time() -> None:
    encoded = wire.encode_stamp(7, None, None)
    assert encoded == bytes([1, 0, 0, 0, 7, 0, 0, 0]) + bytes(16)
    assert wire.decode_stamp(encoded) == wire.RefStamp(7, None, None)


@given(st.integers(0, 2**32 - 1), finite, st.floats(0, 1e6))
def test_stamp_round_trip(ref_id: int, t_ref: float, bound: float) -> None:
    assert wire.decode_stamp(wire.encode_stamp(ref_id, t_ref, bound)) == (ref_id, t_ref, bound)


@pytest.mark.parametrize(
    ("attachment", "says"),
    [
        pytest.param(b"", "expected 24 bytes, got 0", id="empty"),
        pytest.param(bytes(23), "expected 24 bytes, got 23", id="short"),
        pytest.param(bytes(25), "expected 24 bytes, got 25", id="long"),
        pytest.param(bytes([2, 1, 0, 0]) + bytes(20), "version 2", id="version"),
        pytest.param(bytes([1, 3, 0, 0]) + bytes(20), "unknown flags", id="flags"),
        pytest.param(bytes([1, 1, 1, 0]) + bytes(20), "reserved 1", id="reserved"),
        pytest.param(
            bytes([1, 1, 0, 0, 0, 0, 0, 0]) + struct.pack("<dd", math.nan, 0.0),
            "field 0",
            id="nan time",
        ),
        pytest.param(
            bytes([1, 1, 0, 0, 0, 0, 0, 0]) + struct.pack("<dd", 1.0, math.inf),
            "field 1",
            id="inf bound",
        ),
        pytest.param(
            bytes([1, 1, 0, 0, 0, 0, 0, 0]) + struct.pack("<dd", 1.0, -0.1),
            "negative",
            id="negative bound",
        ),
    ],
)
def test_malformed_stamps_are_refused_saying_why(attachment: bytes, says: str) -> None:
    with pytest.raises(DecodeError, match=says):
        wire.decode_stamp(attachment)


@pytest.mark.parametrize(
    ("ref_id", "t_ref", "bound"),
    [(-1, 1.0, 0.0), (2**32, 1.0, 0.0), (0, math.nan, 0.0), (0, 1.0, math.inf), (0, 1.0, -1e-3)],
)
def test_encoding_a_bad_stamp_fails(ref_id: int, t_ref: float, bound: float) -> None:
    with pytest.raises(ValueError):
        wire.encode_stamp(ref_id, t_ref, bound)

"""The serial protocol's codec (docs/serial-protocol.md): frames byte for byte against
hand-built bytes, and the decoder's resynchronisation rules, fuzzed with hypothesis."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.serial.protocol import (
    DEVICE_TO_HOST,
    FLAG_FAILSAFE,
    HOST_TO_DEVICE,
    MAX_PAYLOAD,
    OVERHEAD,
    PAYLOAD_SIZES,
    TYPE_IMU,
    DevicePose,
    FrameDecoder,
    Heartbeat,
    Imu,
    Message,
    Status,
    Valves,
    crc16_ccitt,
    encode,
    encode_frame,
    encode_heartbeat,
    encode_imu,
    encode_pose,
    encode_status,
    encode_valves,
    mask_to_valves,
    valves_to_mask,
)
from federation.core.wire import Pose


def crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE one bit at a time, straight from its definition."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def hand_frame(msg_type: int, payload: bytes) -> bytes:
    body = bytes([msg_type, len(payload)]) + payload
    crc = crc_bitwise(body)
    return b"\xa5\x5a" + body + bytes([crc & 0xFF, crc >> 8])


def f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


# -- CRC and frames, byte for byte ---------------------------------------------
def test_crc_check_value() -> None:
    # The catalogue check value of CRC-16/CCITT-FALSE.
    assert crc16_ccitt(b"123456789") == 0x29B1
    assert crc_bitwise(b"123456789") == 0x29B1


@given(st.binary(max_size=100))
def test_crc_table_matches_bitwise(data: bytes) -> None:
    assert crc16_ccitt(data) == crc_bitwise(data)


def test_valves_and_heartbeat_frames_match_the_documented_bytes() -> None:
    # The two examples written out in docs/serial-protocol.md.
    assert encode_valves(1, 0x06) == bytes.fromhex("a55a 10 05 01000000 06 234f")
    assert encode_valves(1, 0x06) == hand_frame(0x10, bytes([1, 0, 0, 0, 6]))
    hb = bytes.fromhex("a55a 11 0c 01000000 0000000000000440 7e9d")
    assert encode_heartbeat(1, 2.5) == hb
    assert hb[4:16] == struct.pack("<Id", 1, 2.5)
    assert hb[-2:] == crc_bitwise(hb[2:-2]).to_bytes(2, "little")


def test_valves_mask_bit_i_is_valve_i() -> None:
    valves = (False, True, True, False, False, False, False, True)
    frame = encode_valves(0xDEADBEEF, valves)
    assert frame == hand_frame(0x10, bytes([0xEF, 0xBE, 0xAD, 0xDE, 0b1000_0110]))
    assert valves_to_mask(valves) == 0b1000_0110
    assert mask_to_valves(0b1000_0110) == valves


def test_imu_frame_layout() -> None:
    payload = struct.pack("<d", 12.5) + struct.pack("<f", -0.25) + struct.pack("<ff", 0.5, -2.0)
    assert len(payload) == PAYLOAD_SIZES[TYPE_IMU] == 20
    assert encode_imu(12.5, -0.25, 0.5, -2.0) == hand_frame(0x01, payload)


def test_pose_frame_layout() -> None:
    pose = Pose(1.5, -0.75, 0.5, 0.125, -0.0625, 0.25)  # exact in f32
    payload = struct.pack("<d", 3.0) + b"".join(struct.pack("<f", v) for v in pose)
    assert len(payload) == 32
    assert encode_pose(3.0, pose) == hand_frame(0x02, payload)


def test_status_frame_layout() -> None:
    status = Status(7.0, 0b0000_0110, FLAG_FAILSAFE, 200, 11, 12, 13, 14, 15, 2)
    payload = (
        struct.pack("<d", 7.0)
        + bytes([0b0000_0110, 0x01])
        + (200).to_bytes(2, "little")
        + b"".join(n.to_bytes(4, "little") for n in (11, 12, 13, 14, 15, 2))
    )
    assert len(payload) == 36
    assert encode_status(status) == hand_frame(0x03, payload)
    assert status.failsafe
    assert not status._replace(flags=0x02).failsafe


def test_status_counters_wrap_and_timeout_saturates() -> None:
    frame = encode_status(Status(0.0, 0, 0, 70_000, 2**32 + 5, 0, 0, 0, 0, 0))
    (decoded,) = FrameDecoder().feed(frame)
    assert isinstance(decoded, Status)
    assert decoded.heartbeat_timeout_ms == 0xFFFF
    assert decoded.valves_seq == 5


@pytest.mark.parametrize(
    "call",
    [
        lambda: encode_valves(0, (True,) * 7),
        lambda: encode_valves(-1, 0),
        lambda: encode_valves(2**32, 0),
        lambda: encode_valves(0, 256),
        lambda: encode_heartbeat(0, math.nan),
        lambda: encode_imu(0.0, math.inf, 0.0, 0.0),
        lambda: encode_pose(math.nan, Pose()),
        lambda: encode_frame(0x01, bytes(MAX_PAYLOAD + 1)),
        lambda: encode_frame(256, b""),
    ],
)
def test_encoders_refuse_what_the_wire_cannot_carry(call: object) -> None:
    with pytest.raises(ValueError):
        call()  # type: ignore[operator]


# -- decoding ------------------------------------------------------------------
MESSAGES: list[Message] = [
    Imu(1.0, 0.5, -0.25, 0.125),
    DevicePose(1.01, Pose(0.5, 0.25, -1.0, 0.0, 0.125, 0.5)),
    Status(1.02, 3, 2, 200, 4, 5, 6, 7, 8, 9),
    Valves(7, 0x81),
    Heartbeat(8, 123.456),
]


def test_every_message_round_trips() -> None:
    stream = b"".join(encode(m) for m in MESSAGES)
    decoder = FrameDecoder()
    assert decoder.feed(stream) == MESSAGES
    assert decoder.frames_ok == len(MESSAGES)
    assert decoder.garbage_bytes == decoder.bad_checksum == decoder.pending == 0


def test_f32_fields_are_rounded_to_single_precision() -> None:
    (msg,) = FrameDecoder().feed(encode_pose(0.1, Pose(0.1, 0.2, 0.3, 0.4, 0.5, 0.6)))
    assert isinstance(msg, DevicePose)
    assert msg.t == 0.1  # time stays f64
    assert msg.pose == Pose(*(f32(v) for v in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)))
    assert msg.pose.x != 0.1


def test_byte_at_a_time_equals_all_at_once() -> None:
    stream = b"\x00\xa5" + b"".join(encode(m) for m in MESSAGES) + b"\xa5"
    decoder = FrameDecoder()
    got: list[Message] = []
    for i in range(len(stream)):
        got += decoder.feed(stream[i : i + 1])
    assert got == MESSAGES
    assert decoder.garbage_bytes == 2  # the lone 0x00 and 0xa5 before the first frame
    assert decoder.pending == 1  # a trailing 0xa5 may start the next frame


def test_garbage_between_frames_resynchronises_at_the_next_frame() -> None:
    junk = [b"\x00\x01\x02", b"hello world", bytes(range(0x10, 0x40)), b"\x5a\x5a"]
    frames = [encode(m) for m in MESSAGES[:4]]
    stream = b"".join(j + f for j, f in zip(junk, frames, strict=True))
    decoder = FrameDecoder()
    assert decoder.feed(stream) == MESSAGES[:4]
    assert decoder.garbage_bytes == sum(len(j) for j in junk)
    assert decoder.bad_checksum == 0


def test_bad_checksum_is_dropped_and_counted() -> None:
    good = [encode(m) for m in MESSAGES[:3]]
    bad = bytearray(good[1])
    bad[-1] ^= 0x40
    decoder = FrameDecoder()
    assert decoder.feed(good[0] + bytes(bad) + good[2]) == [MESSAGES[0], MESSAGES[2]]
    assert decoder.bad_checksum == 1
    assert decoder.frames_ok == 2
    # A rejected frame's bytes count as garbage: every byte is accounted for.
    assert decoder.garbage_bytes == len(bad)


def test_corrupted_payload_is_a_bad_checksum() -> None:
    frame = bytearray(encode(MESSAGES[1]))
    frame[10] ^= 0x01
    decoder = FrameDecoder()
    assert decoder.feed(bytes(frame)) == []
    assert decoder.bad_checksum == 1


def test_a_corrupted_length_byte_does_not_swallow_the_frames_behind_it() -> None:
    # The first frame's length grows from 5 to 60: the decoder waits for 66 bytes,
    # finds a bad CRC, resumes one byte after the sync and finds every good frame.
    bad = bytearray(encode(Valves(1, 2)))
    bad[3] = 60
    good = [encode(Heartbeat(i, float(i))) for i in range(6)]
    decoder = FrameDecoder(HOST_TO_DEVICE)
    got = decoder.feed(bytes(bad) + b"".join(good))
    assert got == [Heartbeat(i, float(i)) for i in range(6)]
    assert decoder.bad_checksum == 1


def test_oversize_length_is_rejected_without_waiting() -> None:
    header = b"\xa5\x5a\x01" + bytes([MAX_PAYLOAD + 1])
    decoder = FrameDecoder()
    assert decoder.feed(header + encode(MESSAGES[0])) == [MESSAGES[0]]
    assert decoder.oversize == 1
    assert decoder.garbage_bytes == len(header)


def test_unknown_type_with_good_crc_is_consumed_and_counted() -> None:
    host = FrameDecoder(DEVICE_TO_HOST)
    stream = encode(Valves(1, 1)) + hand_frame(0x7F, b"future") + encode(MESSAGES[0])
    assert host.feed(stream) == [MESSAGES[0]]
    assert host.unknown_type == 2  # a host message, and a type nobody knows yet
    assert host.garbage_bytes == host.bad_checksum == 0


def test_wrong_length_for_a_known_type_is_counted() -> None:
    decoder = FrameDecoder()
    assert decoder.feed(hand_frame(TYPE_IMU, bytes(8)) + encode(MESSAGES[3])) == [MESSAGES[3]]
    assert decoder.bad_length == 1


def test_non_finite_values_are_dropped() -> None:
    nan_imu = hand_frame(TYPE_IMU, struct.pack("<dfff", 1.0, math.nan, 0.0, 0.0))
    inf_time = hand_frame(0x11, struct.pack("<Id", 1, math.inf))
    decoder = FrameDecoder()
    assert decoder.feed(nan_imu + inf_time + encode(MESSAGES[0])) == [MESSAGES[0]]
    assert decoder.bad_value == 2


def test_false_sync_inside_garbage_costs_one_bad_frame_at_most() -> None:
    # "A5 5A" followed by a plausible header in the noise: rejected by the CRC.
    noise = b"\xa5\x5a\x01\x14" + bytes(range(30))
    decoder = FrameDecoder()
    assert decoder.feed(noise + encode(MESSAGES[0])) == [MESSAGES[0]]
    assert decoder.bad_checksum == 1
    assert decoder.garbage_bytes == len(noise)


# -- fuzzing -------------------------------------------------------------------
def _accounted(d: FrameDecoder) -> bool:
    return d.bytes_in == d.frame_bytes + d.garbage_bytes + d.pending


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=20))
def test_random_bytes_never_raise_only_count(chunks: list[bytes]) -> None:
    decoder = FrameDecoder()
    for chunk in chunks:
        decoder.feed(chunk)
        assert _accounted(decoder)
        assert decoder.pending <= MAX_PAYLOAD + OVERHEAD
    assert decoder.bytes_in == sum(map(len, chunks))


_message = st.one_of(
    st.builds(
        Imu,
        st.floats(-1e6, 1e6),
        st.floats(-10, 10, width=32),
        st.floats(-10, 10, width=32),
        st.floats(-10, 10, width=32),
    ),
    st.builds(
        DevicePose,
        st.floats(0, 1e6),
        st.builds(Pose, *[st.floats(-100, 100, width=32)] * 6),
    ),
    st.builds(Valves, st.integers(0, 2**32 - 1), st.integers(0, 255)),
    st.builds(Heartbeat, st.integers(0, 2**32 - 1), st.floats(-1e9, 1e9)),
)
_junk = st.binary(max_size=40).map(lambda b: b.replace(b"\xa5", b""))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(_junk, _message), max_size=12), st.lists(st.integers(1, 64)))
def test_frames_between_random_garbage_are_all_recovered(
    items: list[tuple[bytes, Message]], cuts: list[int]
) -> None:
    stream = b"".join(junk + encode(msg) for junk, msg in items)
    decoder = FrameDecoder()
    got: list[Message] = []
    pos = 0
    for size in [*cuts, len(stream)]:
        got += decoder.feed(stream[pos : pos + size])
        pos += size
    assert got == [msg for _, msg in items]
    assert decoder.garbage_bytes == sum(len(junk) for junk, _ in items)
    assert decoder.bad_checksum == decoder.oversize == 0
    assert _accounted(decoder) and decoder.pending == 0


@settings(max_examples=200, deadline=None)
@given(st.lists(_message, min_size=1, max_size=8), st.data())
def test_a_single_bit_error_loses_exactly_its_frame(
    messages: list[Message], data: st.DataObject
) -> None:
    # CRC-16 catches every single-bit error in what it covers (type, payload, CRC;
    # the length byte moves the frame's end, so it is left out here).
    frames = [bytearray(encode(m)) for m in messages]
    k = data.draw(st.integers(0, len(frames) - 1))
    offset = data.draw(st.sampled_from([2, *range(4, len(frames[k]))]))
    frames[k][offset] ^= 1 << data.draw(st.integers(0, 7))
    decoder = FrameDecoder()
    assert decoder.feed(b"".join(frames)) == messages[:k] + messages[k + 1 :]
    assert decoder.bad_checksum >= 1
    assert _accounted(decoder)  # (a trailing 0xa5 of the bad frame may stay pending)

"""The Python side of the serial protocol: COBS, CRC, messages, frames and the stream decoder."""

from __future__ import annotations

import math

import pytest
from hw_support import messages
from hypothesis import given, settings
from hypothesis import strategies as st

from gripper_env.hardware import protocol as proto

# ---- CRC and COBS -------------------------------------------------------------------------------


def test_crc_check_value_and_continuation() -> None:
    # The catalogue check value of CRC-16/CCITT-FALSE.
    assert proto.crc16_ccitt_false(b"123456789") == 0x29B1
    assert proto.crc16_ccitt_false(b"") == 0xFFFF
    assert proto.crc16_ccitt_false(b"6789", proto.crc16_ccitt_false(b"12345")) == 0x29B1


def _crc_bitwise(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


@given(st.binary(max_size=300))
def test_crc_matches_bitwise_definition(data: bytes) -> None:
    assert proto.crc16_ccitt_false(data) == _crc_bitwise(data)


@pytest.mark.parametrize(
    ("raw", "encoded"),
    [
        # Wikipedia's COBS examples.
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x00\x11\x00", b"\x01\x02\x11\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255))),
        (bytes(range(0, 255)), b"\x01\xff" + bytes(range(1, 255))),
        (bytes(range(1, 256)), b"\xff" + bytes(range(1, 255)) + b"\x02\xff"),
        (b"", b"\x01"),
    ],
)
def test_cobs_known_vectors(raw: bytes, encoded: bytes) -> None:
    assert proto.cobs_encode(raw) == encoded
    assert proto.cobs_decode(encoded) == raw


@given(st.binary(max_size=1200))
def test_cobs_round_trip_has_no_zero_and_bounded_overhead(data: bytes) -> None:
    encoded = proto.cobs_encode(data)
    assert 0 not in encoded
    assert len(encoded) <= len(data) + len(data) // 254 + 1
    assert proto.cobs_decode(encoded) == data


@pytest.mark.parametrize("bad", [b"\x00", b"\x03\x11", b"\x02\x11\x00", b"\x05\x01\x02"])
def test_cobs_decode_rejects_malformed(bad: bytes) -> None:
    with pytest.raises(proto.CobsError):
        proto.cobs_decode(bad)


# ---- messages and frames ------------------------------------------------------------------------


def _same(a: proto.Message, b: proto.Message) -> bool:
    """Equal field by field, NaN equal to NaN (compare the wire bytes)."""
    return type(a) is type(b) and a.encode() == b.encode()


@settings(max_examples=300)
@given(messages)
def test_every_message_round_trips(msg: proto.Message) -> None:
    decoded = type(msg).decode(msg.encode())
    assert _same(decoded, msg)
    if not any(isinstance(v, float) and math.isnan(v) for v in vars(msg).values()):
        assert decoded == msg


@settings(max_examples=300)
@given(messages, st.integers(0, 255))
def test_every_frame_round_trips(msg: proto.Message, seq: int) -> None:
    frame = proto.encode_frame(seq, msg)
    assert frame.endswith(b"\x00") and 0 not in frame[:-1]
    got_seq, decoded = proto.decode_frame(frame)
    assert got_seq == seq
    assert _same(decoded, msg)


def test_frame_layout_is_cobs_of_seq_type_payload_crc_le() -> None:
    frame = proto.encode_frame(7, proto.SetMode(proto.Mode.CLOSED_LOOP))
    raw = proto.cobs_decode(frame[:-1])
    assert raw[:3] == bytes([7, 0x03, 2])
    assert raw[3:] == proto.crc16_ccitt_false(raw[:3]).to_bytes(2, "little")


def test_payload_sizes_match_protocol_md() -> None:
    sizes = {
        proto.Hello: 2,
        proto.Configure: 69,
        proto.SetMode: 1,
        proto.Setpoint: 4,
        proto.Heartbeat: 4,
        proto.Estop: 0,
        proto.Info: 29,
        proto.Status: 34,
        proto.ErrorReport: 5,
    }
    for cls, size in sizes.items():
        assert len(cls().encode()) == size, cls.__name__
    sample = proto.TelemetrySample(100, 200, 300, 4)
    assert len(proto.Telemetry(0, 1, (sample,) * 10).encode()) == 77
    assert len(proto.ProfileChunk(0, 3, (1, 2, 3)).encode()) == 10


def test_configure_field_offsets() -> None:
    payload = proto.Configure(p=1.0, decimation=0x1234, sign=-1, telemetry_batch=9).encode()
    assert payload[0:4] == b"\x00\x00\x80\x3f"  # 1.0f little-endian
    assert payload[44:46] == b"\x34\x12"
    assert payload[47] == 0xFF  # int8 -1
    assert payload[49] == 9


@pytest.mark.parametrize(
    ("msg", "field"),
    [
        (proto.Hello(protocol_version=70000), "protocol_version"),
        (proto.SetMode(mode=-1), "mode"),
        (proto.Configure(sign=200), "sign"),
        (proto.Configure(p=1e39), "p"),
        (proto.Setpoint(angle_deg="90"), "angle_deg"),  # type: ignore[arg-type]
        (proto.Heartbeat(token=2**32), "token"),
        (proto.ProfileChunk(0, 1, (40000,)), "samples_cdeg"),
        (proto.ProfileChunk(0, 1, ()), "samples_cdeg"),
        (proto.Telemetry(0, 1, ()), "samples"),
    ],
)
def test_encode_names_the_bad_field(msg: proto.Message, field: str) -> None:
    with pytest.raises(proto.FieldValueError, match=field):
        msg.encode()


def test_encode_frame_refuses_bad_seq_and_long_payload() -> None:
    with pytest.raises(proto.FieldValueError, match="seq"):
        proto.encode_frame(256, proto.Estop())
    with pytest.raises(proto.FrameLengthError):
        proto.encode_raw_frame(0, 0x05, bytes(proto.MAX_PAYLOAD + 1))


def test_decode_errors_name_the_problem() -> None:
    good = proto.encode_frame(1, proto.Setpoint(50.0))
    raw = bytearray(proto.cobs_decode(good[:-1]))
    raw[3] ^= 0x40
    with pytest.raises(proto.CrcError, match="CRC mismatch"):
        proto.decode_frame(proto.cobs_encode(bytes(raw)))
    with pytest.raises(proto.FrameLengthError, match="truncated"):
        proto.decode_frame(proto.cobs_encode(b"\x01\x02\x03"))
    with pytest.raises(proto.UnknownMessageTypeError, match="0x42"):
        proto.decode_frame(proto.encode_raw_frame(0, 0x42, b""))
    with pytest.raises(proto.PayloadLengthError, match="SetMode payload must be 1 bytes, got 2"):
        proto.decode_frame(proto.encode_raw_frame(0, 0x03, b"\x01\x02"))
    with pytest.raises(proto.PayloadLengthError, match="Telemetry"):
        proto.Telemetry.decode(bytes([0, 0, 0, 0, 1, 0, 2]) + bytes(7))
    with pytest.raises(proto.ProtocolError):
        proto.decode_frame(b"\x05\x01\x00")


# ---- the stream decoder -------------------------------------------------------------------------

frames_and_seqs = st.lists(st.tuples(messages, st.integers(0, 255)), min_size=1, max_size=8)


@settings(max_examples=150)
@given(frames_and_seqs, st.data())
def test_decoder_is_independent_of_chunking(items: list, data: st.DataObject) -> None:
    stream = b"".join(proto.encode_frame(seq, msg) for msg, seq in items)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    decoder = proto.FrameDecoder()
    received = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        received += decoder.feed(stream[a:b])
    assert [r.seq for r in received] == [seq for _, seq in items]
    assert all(_same(r.message, msg) for r, (msg, _) in zip(received, items, strict=True))
    assert decoder.stats.rejected == 0 and decoder.stats.discarded_bytes == 0


@settings(max_examples=200)
@given(frames_and_seqs, st.lists(st.binary(max_size=60), min_size=1, max_size=8))
def test_garbage_between_frames_is_skipped(items: list, garbage: list[bytes]) -> None:
    decoder = proto.FrameDecoder()
    received = []
    for (msg, seq), junk in zip(items, garbage * len(items), strict=False):
        # Garbage, then a delimiter ends it; the good frame follows.
        received += decoder.feed(junk + b"\x00" + proto.encode_frame(seq, msg))
    good = [r for r in received if any(_same(r.message, m) for m, _ in items)]
    assert len(good) >= len(items)
    assert [r.seq for r in received][-1] == items[-1][1]
    assert _same(received[-1].message, items[-1][0])


@settings(max_examples=200)
@given(st.binary(max_size=2000), st.lists(st.integers(1, 64), max_size=40), messages)
def test_random_noise_never_raises_and_decoder_resynchronises(
    noise: bytes, chunk_sizes: list[int], msg: proto.Message
) -> None:
    decoder = proto.FrameDecoder()
    pos = 0
    for size in chunk_sizes:
        decoder.feed(noise[pos : pos + size])
        pos += size
    decoder.feed(noise[pos:])
    received = decoder.feed(b"\x00" + proto.encode_frame(9, msg))
    assert len(received) == 1
    assert received[0].seq == 9 and _same(received[0].message, msg)


@settings(max_examples=200)
@given(messages, st.data())
def test_single_byte_corruption_is_always_rejected(msg: proto.Message, data: st.DataObject) -> None:
    # CRC-16 catches every burst of up to 16 bits, so one bad byte in the frame can never pass.
    body = bytes((3, msg.TYPE)) + msg.encode()
    raw = bytearray(body + proto.crc16_ccitt_false(body).to_bytes(2, "little"))
    index = data.draw(st.integers(0, len(raw) - 1))
    raw[index] ^= data.draw(st.integers(1, 255))
    decoder = proto.FrameDecoder()
    assert decoder.feed(proto.cobs_encode(bytes(raw)) + b"\x00") == []
    assert decoder.stats.bad_crc == 1
    assert isinstance(decoder.last_error, proto.CrcError)
    # The next frame is read normally.
    assert len(decoder.feed(proto.encode_frame(4, msg))) == 1


def test_truncated_and_oversized_frames_are_counted() -> None:
    decoder = proto.FrameDecoder()
    frame = proto.encode_frame(0, proto.Setpoint(30.0))
    assert decoder.feed(frame[:3] + b"\x00") == []  # cut short: two raw bytes, no CRC
    assert decoder.stats.truncated == 1
    assert decoder.feed(b"\x01" * 400 + b"\x00") == []
    assert decoder.stats.oversized == 1
    assert decoder.stats.discarded_bytes >= 400
    cut = decoder.feed(frame[:-4] + b"\x00")  # a frame missing its tail: bad COBS or CRC
    assert cut == [] and decoder.stats.bad_cobs + decoder.stats.bad_crc == 1
    assert [r.seq for r in decoder.feed(proto.encode_frame(1, proto.Estop()))] == [1]


def test_unknown_type_and_bad_payload_are_counted_not_raised() -> None:
    decoder = proto.FrameDecoder()
    stream = proto.encode_raw_frame(0, 0x42, b"xyz") + proto.encode_raw_frame(1, 0x03, b"")
    assert decoder.feed(stream) == []
    assert decoder.stats.bad_message == 2 and decoder.stats.frames == 2
    assert isinstance(decoder.last_error, proto.PayloadLengthError)


def test_sequence_gaps_are_counted_and_wrap() -> None:
    decoder = proto.FrameDecoder()
    seqs = [250, 251, 252, 255, 0, 1, 5]
    received = decoder.feed(b"".join(proto.encode_frame(s, proto.Estop()) for s in seqs))
    assert [r.gap for r in received] == [0, 0, 0, 2, 0, 0, 3]
    assert decoder.stats.lost == 5 and decoder.stats.gaps == 2
    decoder.reset_sequence()
    assert decoder.feed(proto.encode_frame(100, proto.Estop()))[0].gap == 0


def test_unsynced_decoder_skips_to_first_delimiter() -> None:
    frame = proto.encode_frame(2, proto.Heartbeat(5))
    decoder = proto.FrameDecoder(synced=False)
    assert decoder.feed(frame[4:]) == []  # the tail of a frame we joined mid-way
    assert decoder.stats.rejected == 0 and decoder.stats.discarded_bytes == len(frame) - 5
    assert decoder.feed(frame)[0].message == proto.Heartbeat(5)


def test_telemetry_sample_units() -> None:
    s = proto.TelemetrySample(2150, proto.CDEG_NONE, 512, proto.Mode.CLOSED_LOOP | 0x20)
    assert s.reference_deg == pytest.approx(21.5)
    assert math.isnan(s.command_deg)
    assert s.mode == proto.Mode.CLOSED_LOOP
    t = proto.Telemetry(1000, 2, (s, s, s))
    assert t.times_us() == [1000, 3000, 5000]

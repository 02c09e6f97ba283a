"""The Python twin of the firmware (gripper_env.hardware.twin.firmware): byte-for-byte parity with
the
C++ Device of gripper_core.h, and the jaw-range property on random host message sequences."""

from __future__ import annotations

import math

from hw_support import field_strategy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.twin.firmware import Firmware

JAW = (21.0, 92.0)

# Host -> device messages with mostly sensible values, sometimes anything the wire allows.
_valid_configure = st.builds(
    proto.Configure,
    p=st.floats(-5, 5, width=32),
    i=st.floats(-20, 20, width=32),
    d=st.floats(-0.015625, 0.015625, width=32),
    n=st.sampled_from([50.0, 100.0, 1999.0]),
    u_min=st.sampled_from([-math.inf, 0.0, 21.0, 40.0]),
    u_max=st.sampled_from([math.inf, 60.0, 92.0, 180.0]),
    jaw_min=st.sampled_from([21.0, 30.0]),
    jaw_max=st.sampled_from([92.0, 80.0]),
    adc_at_lo=st.integers(4, 500),
    adc_at_hi=st.integers(520, 1019),
    decimation=st.integers(0, 3),
    anti_windup=st.integers(0, 2),
    sign=st.sampled_from([1, -1]),
    d_on_meas=st.integers(0, 1),
    telemetry_batch=st.integers(1, 32),
    grasp=st.integers(0, 1),
    grasp_squeeze_deg=st.floats(0.25, 3.0, width=32),
    grasp_push_deg=st.floats(3.5, 8.0, width=32),
    grasp_short_deg=st.floats(0.25, 2.0, width=32),
    grasp_still_deg=st.floats(0.5, 2.0, width=32),
    grasp_dwell_ticks=st.integers(1, 40),  # within a step's ticks: the mode engages and lets go
)
_any_configure = st.builds(proto.Configure, *[field_strategy(c) for c in proto.Configure._FORMAT])
host_messages = st.one_of(
    st.just(proto.Hello()),
    st.builds(proto.Hello, st.integers(0, 3)),
    _valid_configure,
    _any_configure,
    st.builds(proto.SetMode, st.integers(0, 3)),
    st.builds(proto.Setpoint, st.floats(width=32)),
    st.builds(proto.Setpoint, st.floats(-100, 300, width=32)),
    st.builds(proto.Heartbeat, st.integers(0, 2**32 - 1)),
    st.just(proto.Estop()),
)
# One step of a host session: a message (as a good frame, a corrupted one or raw noise), then
# some control ticks with an ADC reading.
steps = st.tuples(
    host_messages,
    st.sampled_from(["frame", "frame", "frame", "corrupt", "noise"]),
    st.integers(0, 40),
    st.integers(0, 1023),
)


def _wire(msg: proto.Message, seq: int, how: str, noise: bytes = b"\x13\x00\x7f") -> bytes:
    frame = proto.encode_frame(seq, msg)
    if how == "corrupt":
        return frame[:-2] + bytes([frame[-2] ^ 0x40 or 1]) + b"\x00"
    if how == "noise":
        return noise + frame
    return frame


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(steps, min_size=1, max_size=25), st.booleans())
def test_no_host_message_sequence_commands_outside_the_jaw_range(session, only_default_jaw):
    fw = Firmware(device_id=1)
    now = 0
    for seq, (msg, how, ticks, adc) in enumerate(session):
        if only_default_jaw and isinstance(msg, proto.Configure):
            msg = proto.Configure(**{**msg.__dict__, "jaw_min": JAW[0], "jaw_max": JAW[1]})
        fw.receive(_wire(msg, seq & 0xFF, how), now)
        for _ in range(ticks):
            fw.tick(now, adc)
            now += 1000
            lo, hi = fw.cfg.jaw_min, fw.cfg.jaw_max
            assert 0.0 <= lo < hi <= 180.0
            if only_default_jaw:
                assert (lo, hi) == JAW
            if fw.servo_on:
                assert lo <= fw.servo_command_deg <= hi, (fw.servo_command_deg, lo, hi)
                assert 400.0 <= fw.servo_pulse_us() <= 2600.0
            if fw.mode == proto.Mode.IDLE:
                assert fw.servo_command_deg == hi  # idle holds the safe (open) position
        fw.take_tx()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(steps, min_size=1, max_size=12))
def test_the_python_twin_sends_the_same_bytes_as_the_cpp_device(harness, session):
    fw = Firmware(device_id=0xC0FFEE)
    assert harness("dev_begin", 0xC0FFEE, 0) == "OK"
    now = 0
    for seq, (msg, how, ticks, adc) in enumerate(session):
        data = _wire(msg, seq & 0xFF, how)
        fw.receive(data, now)
        assert fw.take_tx().hex() == _hex(harness("dev_rx", data.hex()))
        if ticks:
            summary = harness("dev_tick", ticks, adc).split()
            for _ in range(ticks):
                fw.tick(now, adc)
                now += 1000
            assert int(summary[0]) == fw.mode and int(summary[1]) == fw.faults
            assert fw.take_tx().hex() == _hex(summary[10])


def _hex(token: str) -> str:
    return "" if token == "-" else token


# Line noise: frames of every kind, cut, corrupted and glued to random bytes with zeros in them.
_frames = st.builds(proto.encode_frame, st.integers(0, 255), host_messages)
_chunks = st.one_of(
    _frames,
    _frames.map(lambda f: f[: len(f) // 2]),
    _frames.map(lambda f: bytes([f[0] ^ 0x21]) + f[1:]),
    st.binary(max_size=300),
    st.binary(min_size=240, max_size=260).map(lambda b: b.replace(b"\x00", b"\x01") + b"\x00"),
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_chunks, max_size=8))
def test_the_streaming_decoder_judges_line_noise_like_the_python_twin(harness, chunks) -> None:
    # The firmware decodes COBS and checks the CRC byte by byte; the twin decodes whole frames.
    fw = Firmware(device_id=1)
    assert harness("dev_begin", 1, 0) == "OK"
    for data in chunks:
        fw.receive(data, 0)
        assert fw.take_tx().hex() == _hex(harness("dev_rx", data.hex() or "-"))
    rx = fw.rx.stats
    expected = [rx.frames, rx.bad_cobs, rx.bad_crc, rx.truncated, rx.oversized, rx.damaged]
    expected += [rx.lost, rx.discarded_bytes, fw.rx_overflow]
    assert [int(x) for x in harness("dev_counters").split()] == expected

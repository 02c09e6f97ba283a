"""Safety functions and the device state machine of gripper_core.h, on a simulated clock."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from gripper_env.hardware import protocol as proto

JAW = (21.0, 92.0)  # the default jaw range, and the hard range compiled into the image
# The hard pulse window in 0.5 us ticks: 21 and 92 deg with the build's 544/2400 us mapping,
# rounded to the nearest tick (computed here from the datasheet mapping, not by the firmware).
PULSE_HARD = (round(2 * (544 + 21 * 1856 / 180)), round(2 * (544 + 92 * 1856 / 180)))
CAL = (200, 600)  # ADC counts at 21 and 92 deg in these tests


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


# ---- pure safety functions ----------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True))
def test_clamp_never_leaves_the_jaw_range(harness, harness_f32, x: float) -> None:
    for h in (harness, harness_f32):
        got = float.fromhex(h("clamp", float(x).hex(), "21", "92", "92"))
        assert JAW[0] <= got <= JAW[1]
        if math.isnan(x):
            assert got == 92.0  # NaN goes to the safe open position
        elif JAW[0] <= x <= JAW[1]:
            assert got == pytest.approx(x, rel=1e-7)


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.floats(-400, 400),
        st.integers(-40000, 40000).map(lambda c: c / 100 + 0.005),  # halfway cases
    )
)
def test_centi_degrees_round_half_away_from_zero_like_the_twin(harness, harness_f32, x) -> None:
    from fractions import Fraction

    from gripper_env.hardware.twin.firmware import _to_cdeg

    for h, value in ((harness, x), (harness_f32, _f32(x) if abs(x) < 3.4e38 else x)):
        got = int(h("cdeg", float(value).hex()))
        assert got == _to_cdeg(value)
        if math.isnan(value):
            assert got == proto.CDEG_NONE
        else:  # independent truth: the exact product, rounded half away from zero, saturated
            c = Fraction(32767) if math.isinf(value) else abs(Fraction(value) * 100)
            want = min(int(c + Fraction(1, 2)), 32767)
            assert got == (-want if value < 0 else want)


def test_adc_angle_conversion_is_the_two_point_line(harness) -> None:
    assert float.fromhex(harness("adc2deg", 200, *CAL)) == 21.0
    assert float.fromhex(harness("adc2deg", 600, *CAL)) == 92.0
    assert float.fromhex(harness("adc2deg", 400, *CAL)) == pytest.approx(56.5)
    # Reversed wiring (counts fall as the jaw opens) works the same way.
    assert float.fromhex(harness("adc2deg", 300, 700, 300)) == 92.0
    for deg in (21.0, 40.0, 56.5, 92.0):
        adc = int(harness("deg2adc", float(deg).hex(), *CAL))
        assert abs(float.fromhex(harness("adc2deg", adc, *CAL)) - deg) <= 71 / 400 / 2 + 1e-9
    assert int(harness("deg2adc", "1e9", *CAL)) == 1023
    assert int(harness("deg2adc", "-1e9", *CAL)) == 0


@settings(max_examples=200, deadline=None)
@given(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(400, 2600),
    st.integers(400, 2600),
)
def test_servo_pulse_stays_inside_hard_limits(
    harness_f32, deg: float, us0: int, us180: int
) -> None:
    ticks = int(harness_f32("pulse", float(deg).hex(), us0, us180))
    assert PULSE_HARD[0] <= ticks <= PULSE_HARD[1]


def test_servo_pulse_resolution_is_half_a_microsecond(harness, harness_f32) -> None:
    assert PULSE_HARD == (1521, 2985)  # 760.5 and 1492.5 us
    for h in (harness, harness_f32):
        assert h("window") == f"{PULSE_HARD[0]} {PULSE_HARD[1]}"
    assert int(harness_f32("pulse", "21", 544, 2400)) == PULSE_HARD[0]
    assert int(harness_f32("pulse", "92", 544, 2400)) == PULSE_HARD[1]
    assert int(harness_f32("pulse", "56", 544, 2400)) == round(2 * (544 + 56 * 1856 / 180))
    # Outside the hard range the pulse stops at the window, whatever the mapping.
    assert int(harness_f32("pulse", "0", 544, 2400)) == PULSE_HARD[0]
    assert int(harness_f32("pulse", "180", 544, 2400)) == PULSE_HARD[1]
    assert int(harness_f32("pulse", "21", 2400, 544)) == PULSE_HARD[1]  # reversed: 2183 us
    # 0.05 deg more is 0.5 us more: one timer tick.
    a = int(harness_f32("pulse", "45", 1000, 2000))
    b = int(harness_f32("pulse", "45.09", 1000, 2000))
    assert b - a == 1


@pytest.mark.parametrize(
    ("now", "last", "expired"),
    [
        (499_999, 0, False),
        (500_000, 0, True),
        # Across the 32-bit micros() wrap.
        (100, 2**32 - 499_899, False),
        (100, 2**32 - 499_900, True),
    ],
)
def test_watchdog_expiry_is_wrap_safe(harness, now: int, last: int, expired: bool) -> None:
    assert harness("wd", now, last, 500_000) == ("1" if expired else "0")


# ---- the device, through the harness ----------------------------------------------------------


@dataclass
class Summary:
    mode: int
    faults: int
    servo_on: bool
    ticks_on: int
    cmd_min: float
    cmd_max: float
    pulse_min: int
    pulse_max: int
    jaw_min: float
    jaw_max: float
    replies: list[proto.Message] = field(default_factory=list)


class Host:
    """Plays the host against the harness's device; decodes everything the device sends."""

    def __init__(self, h, device_id: int = 0xC0FFEE) -> None:
        self.h = h
        self.seq = 0
        self.decoder = proto.FrameDecoder()
        assert h("dev_begin", device_id, 0) == "OK"

    def _decode(self, hexed: str) -> list[proto.Message]:
        data = b"" if hexed == "-" else bytes.fromhex(hexed)
        return [r.message for r in self.decoder.feed(data)]

    def raw(self, data: bytes) -> list[proto.Message]:
        return self._decode(self.h("dev_rx", data.hex() or "-"))

    def send(self, msg: proto.Message) -> list[proto.Message]:
        frame = proto.encode_frame(self.seq, msg)
        self.seq = (self.seq + 1) & 0xFF
        return self.raw(frame)

    def _summary(self, answer: str) -> Summary:
        t = answer.split()
        return Summary(
            int(t[0]),
            int(t[1]),
            t[2] == "1",
            int(t[3]),
            float.fromhex(t[4]),
            float.fromhex(t[5]),
            int(t[6]),
            int(t[7]),
            float.fromhex(t[8]),
            float.fromhex(t[9]),
            self._decode(t[10]),
        )

    def tick(self, n: int, adc: int = 400) -> Summary:
        return self._summary(self.h("dev_tick", n, adc))

    def sim(self, n: int, tau_ms: float = 40.0) -> tuple[Summary, float]:
        answer = self.h("dev_sim", n, tau_ms, *CAL).rsplit(" ", 1)
        return self._summary(answer[0]), float.fromhex(answer[1])

    def counters(self) -> list[int]:
        return [int(x) for x in self.h("dev_counters").split()]

    def start(self, **config: float) -> None:
        (info,) = self.send(proto.Hello())
        assert isinstance(info, proto.Info)
        cfg = {"p": 1.0, "i": 9.0, "d": -0.001, "adc_at_lo": CAL[0], "adc_at_hi": CAL[1]}
        cfg.update(config)
        (status,) = self.send(proto.Configure(**cfg))
        assert isinstance(status, proto.Status), status


def _only(replies: list[proto.Message], cls: type) -> proto.Message:
    assert len(replies) == 1 and isinstance(replies[0], cls), replies
    return replies[0]


def test_handshake_info_and_refusals_before_hello(harness) -> None:
    host = Host(harness, device_id=0x12345678)
    err = _only(host.send(proto.SetMode(proto.Mode.OPEN_LOOP)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.NO_SESSION and err.msg_type == proto.SetMode.TYPE
    err = _only(host.send(proto.Hello(protocol_version=1)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.VERSION_MISMATCH and err.detail == proto.PROTOCOL_VERSION
    err = _only(host.send(proto.Setpoint(40.0)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.NO_SESSION
    summary = host.tick(50)
    assert not summary.servo_on and summary.ticks_on == 0 and summary.replies == []
    info = _only(host.send(proto.Hello()), proto.Info)
    assert info == proto.Info(
        proto.PROTOCOL_VERSION, 0, 3, 0, 0x12345678, 1000, 32, 240, 21.0, 92.0, 760.5, 1492.5
    )


def test_commands_are_validated(harness) -> None:
    host = Host(harness)
    host.send(proto.Hello())
    err = _only(host.send(proto.SetMode(proto.Mode.CLOSED_LOOP)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.NOT_CONFIGURED
    cases = [
        (proto.Configure(p=math.nan), 0),
        (proto.Configure(n=2000.0), 3),  # N*dt = 2: unstable filter
        (proto.Configure(u_min=50.0, u_max=40.0), 5),
        (proto.Configure(jaw_min=-5.0), 7),
        (proto.Configure(jaw_max=181.0), 8),
        # the hard jaw range: no wider range, at either end, however consistent
        (proto.Configure(jaw_min=0.0, jaw_max=180.0), 7),
        (proto.Configure(jaw_min=20.9), 7),
        (proto.Configure(jaw_max=92.1), 8),
        # the pulse mapping must keep the jaw range's pulses in the hard window
        (proto.Configure(servo_us_at_0=2400, servo_us_at_180=544), 11),  # reversed: 159 deg
        (proto.Configure(servo_us_at_0=500, servo_us_at_180=2400), 11),  # 21 deg -> 743 us
        (proto.Configure(servo_us_at_0=544, servo_us_at_180=2600), 11),  # 92 deg -> 1595 us
        (proto.Configure(adc_at_lo=0), 9),
        (proto.Configure(adc_at_lo=500, adc_at_hi=510), 10),
        (proto.Configure(servo_us_at_180=3000), 12),
        (proto.Configure(anti_windup=3), 14),
        (proto.Configure(sign=0), 15),
        (proto.Configure(telemetry_batch=33), 17),
        # the grasp mode: its switch, and its settings while it is on
        (proto.Configure(grasp=2), 18),
        (proto.Configure(grasp_squeeze_deg=0.0), 19),
        (proto.Configure(grasp_push_deg=1.0), 20),  # not beyond the squeeze (1 deg)
        (proto.Configure(grasp_short_deg=math.nan), 21),
        (proto.Configure(grasp_still_deg=-1.0), 22),
        (proto.Configure(grasp_dwell_ticks=0), 23),
    ]
    for msg, field_index in cases:
        err = _only(host.send(msg), proto.ErrorReport)
        assert (err.code, err.detail) == (proto.ErrorCode.BAD_VALUE, field_index), msg
    for value in (math.nan, math.inf, -math.inf):
        err = _only(host.send(proto.Setpoint(value)), proto.ErrorReport)
        assert err.code == proto.ErrorCode.BAD_VALUE
    assert host.send(proto.Setpoint(50.0)) == []  # accepted silently
    err = _only(host.send(proto.ProfileChunk(0, 2, (2100, 9200))), proto.ErrorReport)
    assert err.code == proto.ErrorCode.UNSUPPORTED
    err = _only(host.raw(proto.encode_raw_frame(host.seq, 0x03, b"\x01\x02")), proto.ErrorReport)
    assert (err.code, err.detail) == (proto.ErrorCode.BAD_LENGTH, 2)
    host.seq += 1
    err = _only(host.raw(proto.encode_raw_frame(host.seq, 0x42, b"")), proto.ErrorReport)
    assert err.code == proto.ErrorCode.UNKNOWN_TYPE
    host.seq += 1
    # with the grasp mode off its settings are not looked at
    off = proto.Configure(grasp=0, grasp_squeeze_deg=math.nan, grasp_dwell_ticks=0)
    assert isinstance(_only(host.send(off), proto.Status), proto.Status)
    status = _only(host.send(proto.Heartbeat(token=77)), proto.Status)
    assert status.echo == 77 and status.refused == 30 and status.frames_lost == 0
    assert math.isclose(status.setpoint_deg, 50.0) and status.rx_overflow == 0


def test_a_mapping_that_narrows_the_range_is_accepted_and_pulses_stay_inside(harness) -> None:
    host = Host(harness)
    host.send(proto.Hello())
    # 550/2390 us: 21 deg -> 764.5 us, 92 deg -> 1490.4 us, both inside the window
    status = _only(
        host.send(proto.Configure(servo_us_at_0=550, servo_us_at_180=2390)), proto.Status
    )
    assert status.flags & proto.StatusFlag.CONFIGURED
    host.send(proto.Setpoint(10.0))
    host.send(proto.SetMode(proto.Mode.OPEN_LOOP))
    s = host.tick(5)
    assert s.cmd_min == s.cmd_max == 21.0
    assert s.pulse_min == s.pulse_max == int(2 * 550 + 0.5 + 21 * 2 * 1840 / 180)
    assert PULSE_HARD[0] <= s.pulse_min


def test_open_loop_command_is_clamped_and_telemetry_reports_it(harness) -> None:
    host = Host(harness)
    host.send(proto.Hello())
    host.send(proto.Setpoint(150.0))
    _only(host.send(proto.SetMode(proto.Mode.OPEN_LOOP)), proto.Status)
    s = host.tick(20, adc=333)
    assert s.servo_on and s.cmd_min == s.cmd_max == 92.0
    telemetry = [m for m in s.replies if isinstance(m, proto.Telemetry)]
    assert [t.t0_us for t in telemetry] == [0, 10_000] and telemetry[0].decimation == 1
    sample = telemetry[1].samples[-1]
    assert sample.command_cdeg == 9200 and sample.adc == 333
    assert sample.mode == proto.Mode.OPEN_LOOP
    assert sample.flags & proto.SampleFlag.CLAMPED and sample.flags & proto.SampleFlag.SERVO_ON
    host.send(proto.Setpoint(45.5))
    s = host.tick(10)
    assert s.cmd_min == s.cmd_max == 45.5
    assert s.pulse_min == round(2 * (544 + 45.5 * 1856 / 180))
    # The device's frames carry consecutive sequence numbers.
    assert host.decoder.stats.lost == 0 and host.decoder.stats.rejected == 0


def test_closed_loop_reaches_the_reference_on_a_simulated_servo(harness) -> None:
    host = Host(harness)
    host.start(decimation=0)
    host.send(proto.Setpoint(21.0))
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
    for _ in range(10):  # 2 s with a heartbeat every 200 ms
        summary, y = host.sim(200)
        host.send(proto.Heartbeat(1))
        assert JAW[0] <= summary.cmd_min <= summary.cmd_max <= JAW[1]
    assert summary.mode == proto.Mode.CLOSED_LOOP and summary.faults == 0
    assert abs(y - 21.0) < 0.5
    host.send(proto.Setpoint(92.0))
    for _ in range(10):
        summary, y = host.sim(200)
        host.send(proto.Heartbeat(2))
    assert abs(y - 92.0) < 0.5


def test_watchdog_opens_the_gripper_after_500_ms_of_silence(harness) -> None:
    host = Host(harness)
    host.start()
    host.send(proto.Setpoint(30.0))
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))  # at t = 0
    s = host.tick(400, adc=250)  # ticks at t = 0 .. 399 ms
    assert s.mode == proto.Mode.CLOSED_LOOP
    host.send(proto.Heartbeat(5))  # at t = 400 ms: the watchdog restarts
    s = host.tick(500, adc=250)  # ticks at t = 400 .. 899 ms
    assert s.mode == proto.Mode.CLOSED_LOOP and s.faults == 0
    s = host.tick(1, adc=250)  # t = 900 ms: 500 ms of silence
    assert s.mode == proto.Mode.IDLE and s.faults == proto.Fault.WATCHDOG
    assert s.servo_on and s.cmd_min == s.cmd_max == 92.0
    status = [m for m in s.replies if isinstance(m, proto.Status)]
    assert status and status[0].faults == proto.Fault.WATCHDOG
    assert status[0].device_time_us == 900_000
    # Latched: no active mode until acknowledged.
    err = _only(host.send(proto.SetMode(proto.Mode.OPEN_LOOP)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.FAULT_LATCHED and err.detail == proto.Fault.WATCHDOG
    assert _only(host.send(proto.SetMode(proto.Mode.IDLE)), proto.Status).faults == 0
    assert _only(host.send(proto.SetMode(proto.Mode.OPEN_LOOP)), proto.Status).faults == 0


def test_watchdog_is_not_armed_while_idle(harness) -> None:
    host = Host(harness)
    host.start()
    s = host.tick(2000)
    assert s.faults == 0 and s.mode == proto.Mode.IDLE


def test_estop_is_honoured_without_session_and_latched(harness) -> None:
    host = Host(harness)
    status = _only(host.send(proto.Estop()), proto.Status)
    assert status.faults == proto.Fault.ESTOP
    host.start()  # HELLO clears it
    host.send(proto.Setpoint(25.0))
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
    host.tick(100, adc=300)
    status = _only(host.send(proto.Estop()), proto.Status)
    assert status.mode == proto.Mode.IDLE and status.faults == proto.Fault.ESTOP
    s = host.tick(5)
    assert s.cmd_min == s.cmd_max == 92.0
    err = _only(host.send(proto.SetMode(proto.Mode.CLOSED_LOOP)), proto.ErrorReport)
    assert err.code == proto.ErrorCode.FAULT_LATCHED
    assert host.send(proto.Heartbeat(0))[0].faults == proto.Fault.ESTOP  # still latched
    host.send(proto.SetMode(proto.Mode.IDLE))
    assert _only(host.send(proto.SetMode(proto.Mode.CLOSED_LOOP)), proto.Status).faults == 0


def test_broken_potentiometer_wire_stops_closed_loop(harness) -> None:
    host = Host(harness)
    host.start()
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
    s = host.tick(19, adc=0)
    assert s.mode == proto.Mode.CLOSED_LOOP
    s = host.tick(1, adc=0)
    assert s.mode == proto.Mode.IDLE and s.faults == proto.Fault.SENSOR
    assert s.cmd_max == 92.0


def test_numeric_overflow_on_the_board_stops_safely(harness_f32) -> None:
    host = Host(harness_f32)
    host.start(p=3e38, i=0.0, d=0.0, u_min=-math.inf, u_max=math.inf)
    host.send(proto.Setpoint(21.0))
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
    s = host.tick(3, adc=600)  # at 92 deg: P * e overflows float32
    assert s.mode == proto.Mode.IDLE and s.faults == proto.Fault.NUMERIC
    assert JAW[0] <= s.cmd_min <= s.cmd_max <= JAW[1]


def test_device_counts_link_errors(harness) -> None:
    host = Host(harness)
    host.send(proto.Hello())
    host.raw(b"\x13\x37garbage\x00")
    frame = bytearray(proto.cobs_decode(proto.encode_frame(host.seq, proto.Setpoint(30.0))[:-1]))
    frame[3] ^= 0xFF
    host.raw(proto.cobs_encode(bytes(frame)) + b"\x00")  # bad CRC: lost frame
    lost_from = host.seq
    host.seq += 3  # and two more never sent
    lost, status = host.send(proto.Heartbeat(9))
    # the device says at once which frames it missed, then answers the HEARTBEAT
    assert lost == proto.ErrorReport(proto.ErrorCode.FRAMES_LOST, 0, lost_from, 3)
    assert status.bad_crc == 1 and status.bad_frame == 1 and status.frames_lost == 3
    assert status.frames_ok == 2 and status.last_rx_seq == host.seq - 1
    assert status.refused == 0  # a loss report is not a refusal
    counts = host.counters()
    frames_ok, bad_cobs, bad_crc, truncated, oversized, damaged, lost_frames = counts[:7]
    assert (frames_ok, bad_crc, lost_frames, damaged) == (2, 1, 3, 0)
    assert bad_cobs + truncated + oversized == 1


def test_bytes_lost_before_the_decoder_drop_their_frame_and_are_counted(harness) -> None:
    host = Host(harness)
    host.send(proto.Hello())
    frame = proto.encode_frame(host.seq, proto.Setpoint(30.0))
    host.seq += 1
    # two bytes lost in the middle of the frame (a full receive buffer): even if what is left
    # passed the CRC, the frame is dropped
    host.raw(frame[:3])
    assert harness("dev_lost", 2) == "OK"
    host.raw(frame[5:])
    lost, status = host.send(proto.Heartbeat(1))
    assert isinstance(lost, proto.ErrorReport) and lost.code == proto.ErrorCode.FRAMES_LOST
    assert (lost.seq, lost.detail) == (host.seq - 2, 1)
    assert status.rx_overflow == 2 and status.bad_frame == 1 and math.isnan(status.setpoint_deg)
    # a loss right after a delimiter drops the frame that follows, intact as it is
    host.raw(b"\x00")
    assert harness("dev_lost", 1) == "OK"
    assert host.send(proto.Setpoint(40.0)) == []
    lost, status = host.send(proto.Heartbeat(2))
    assert lost.code == proto.ErrorCode.FRAMES_LOST and (lost.seq, lost.detail) == (
        host.seq - 2,
        1,
    )
    assert status.rx_overflow == 3 and status.bad_frame == 2 and math.isnan(status.setpoint_deg)


# ---- property: nothing the host sends moves the servo outside the jaw range -------------------

finite_or_wild = st.one_of(
    st.floats(width=32),
    st.sampled_from([math.nan, math.inf, -math.inf, 3e38, -3e38, 0.0]),
)
in_jaw = st.floats(21.0, 92.0, width=32)


def configure_strategy(jaw: st.SearchStrategy) -> st.SearchStrategy:
    gain = st.one_of(st.floats(-20, 20, width=32), finite_or_wild)
    return st.builds(
        proto.Configure,
        p=gain,
        i=gain,
        d=st.one_of(st.floats(-0.125, 0.125, width=32), finite_or_wild),
        n=st.one_of(st.floats(1, 1999, width=32), finite_or_wild),
        u_min=st.one_of(st.floats(0, 100, width=32), finite_or_wild),
        u_max=st.one_of(st.floats(0, 200, width=32), finite_or_wild),
        kb=gain,
        jaw_min=jaw,
        jaw_max=jaw,
        adc_at_lo=st.integers(0, 1100),
        adc_at_hi=st.integers(0, 1100),
        servo_us_at_0=st.integers(300, 2700),
        servo_us_at_180=st.integers(300, 2700),
        decimation=st.integers(0, 1200),
        anti_windup=st.integers(0, 3),
        sign=st.integers(-2, 2),
        d_on_meas=st.integers(0, 2),
        telemetry_batch=st.integers(0, 40),
    )


def valid_configure(jaw: st.SearchStrategy) -> st.SearchStrategy:
    """Configurations the device accepts (with the jaw range drawn from ``jaw``)."""
    return st.builds(
        lambda gains, aw, sign, dmeas, lo, span: proto.Configure(
            p=gains[0],
            i=gains[1],
            d=gains[2],
            n=100.0,
            u_min=-math.inf,
            u_max=math.inf,
            kb=gains[3],
            jaw_min=lo,
            jaw_max=lo + span,
            adc_at_lo=CAL[0],
            adc_at_hi=CAL[1],
            anti_windup=aw,
            sign=sign,
            d_on_meas=dmeas,
            telemetry_batch=10,
        ),
        st.tuples(*[st.floats(-50, 50, width=32)] * 4),
        st.integers(0, 2),
        st.sampled_from([1, -1]),
        st.integers(0, 1),
        jaw,
        st.floats(1, 40, width=32),
    )


def actions(jaw: st.SearchStrategy, valid_jaw: st.SearchStrategy) -> st.SearchStrategy:
    """A host session: maybe a HELLO, a valid CONFIGURE and an active mode, then anything.

    Every step is a message (or line noise) followed by a burst of control ticks at one ADC
    reading, so whatever the message did is exercised before the next one arrives.
    """
    prefix = st.integers(0, 3).flatmap(
        lambda k: st.tuples(valid_configure(valid_jaw), st.integers(1, 2)).map(
            lambda cm: [proto.Hello(), cm[0], proto.SetMode(cm[1])][:k]
        )
    )
    message = st.one_of(
        st.builds(proto.SetMode, st.sampled_from([0, 1, 1, 2, 2, 2, 3])),
        st.builds(proto.Setpoint, st.one_of(st.floats(-100, 300, width=32), finite_or_wild)),
        valid_configure(valid_jaw),
        configure_strategy(jaw),
        st.builds(proto.Hello, st.sampled_from([1, 1, 1, 0, 2])),
        st.builds(proto.Heartbeat, st.integers(0, 2**32 - 1)),
        st.just(proto.Estop()),
        # Line noise; usually ended by a delimiter, otherwise it also corrupts the next frame.
        st.binary(max_size=40).map(lambda b: b + b"\x00"),
        st.binary(max_size=40),
    )
    ticks = st.tuples(st.integers(0, 700), st.one_of(st.integers(150, 650), st.integers(0, 1023)))
    return st.tuples(
        prefix.map(lambda msgs: [(m, (1, 400)) for m in msgs]),
        st.lists(st.tuples(message, ticks), min_size=1, max_size=20),
    ).map(lambda t: t[0] + t[1])


def _run_and_check(h, steps: list, hard_jaw: tuple[float, float] = JAW) -> None:
    host = Host(h)
    expected_jaw = JAW
    for msg, (n_ticks, adc) in steps:
        replies = host.raw(msg) if isinstance(msg, bytes) else host.send(msg)
        accepted = [m for m in replies if isinstance(m, proto.Status | proto.Info)]
        if isinstance(msg, proto.Configure) and accepted:
            expected_jaw = (_f32(msg.jaw_min), _f32(msg.jaw_max))
        if isinstance(msg, proto.Hello) and accepted:
            expected_jaw = JAW
        s = host.tick(n_ticks, adc)
        assert (s.jaw_min, s.jaw_max) == expected_jaw
        if s.ticks_on:
            event(f"servo on, mode {s.mode}")
            assert not math.isnan(s.cmd_min) and not math.isnan(s.cmd_max)
            assert expected_jaw[0] <= s.cmd_min <= s.cmd_max <= expected_jaw[1]
            assert hard_jaw[0] <= s.cmd_min <= s.cmd_max <= hard_jaw[1]
            assert PULSE_HARD[0] <= s.pulse_min <= s.pulse_max <= PULSE_HARD[1]
        if s.mode != proto.Mode.IDLE:
            assert s.faults == 0


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(actions(st.one_of(in_jaw, finite_or_wild), st.floats(21.0, 52.0, width=32)))
def test_random_host_traffic_never_leaves_the_jaw_range(harness_f32, steps: list) -> None:
    # Configurations whose jaw range lies inside [21, 92] (or is rejected): the commands stay
    # inside [21, 92] whatever else arrives.
    _run_and_check(harness_f32, steps)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    actions(
        st.one_of(st.floats(-10, 200, width=32), finite_or_wild),
        st.one_of(st.floats(0, 140, width=32), st.floats(21.0, 52.0, width=32)),
    )
)
def test_no_jaw_range_or_mapping_moves_the_servo_outside_the_hard_range(
    harness, steps: list
) -> None:
    # Wider or shifted jaw ranges and any pulse mapping: refused, so the commands and the pulses
    # stay inside the hard range compiled into the image, and inside any accepted range.
    _run_and_check(harness, steps)

"""The compiled image under simavr against a hostile link: a command right behind a burst of line
noise is executed, no CONFIGURE moves the jaw outside the hard range, 100,000 fuzzed frames are
judged (pulses on the pin, frames accepted, losses reported), and an overloaded receive path
counts and reports what it loses."""

from __future__ import annotations

import numpy as np
import pytest
from emulator_support import FRAME_CYCLES, new_board, pulse_cycles, session

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.link_fuzz import HARD_WINDOW_US, fuzz_image
from gripper_env.hardware.emulator.mega2560 import CYCLES_PER_US, Mega2560
from gripper_env.hardware.protocol import Mode

# the hard window from the datasheet mapping: 21 and 92 deg at 544 + deg * 1856 / 180 us
HARD_CYCLES = (pulse_cycles(21.0), pulse_cycles(92.0))


def test_the_hard_window_is_the_jaw_range_under_the_servo_mapping() -> None:
    assert HARD_WINDOW_US == (760.5, 1492.5)
    assert HARD_CYCLES == (round(760.5 * CYCLES_PER_US), round(1492.5 * CYCLES_PER_US))


@pytest.mark.parametrize("noise_bytes", [1024, 4096])
def test_a_command_right_behind_a_noise_burst_is_executed(emulator_build, noise_bytes) -> None:
    # issue 21: after >= 1 KiB of random bytes and a 0x00, SETPOINT + SET_MODE(open loop) sent at
    # once were lost (0 pulses, the board stayed IDLE, nothing reported): the receive buffer of
    # the Arduino core overflowed. Now every byte reaches the decoder.
    board = new_board(emulator_build)
    host = session(board)
    noise = np.random.default_rng(noise_bytes).integers(0, 256, noise_bytes, dtype=np.uint8)
    since, start = host.ms, board.mega.cycle
    host.send_raw(noise.tobytes() + b"\x00")
    host.send(proto.Setpoint(40.0))
    host.send(proto.SetMode(Mode.OPEN_LOOP))
    host.run(noise_bytes // 80 + 100)  # the noise takes ~11 us a byte on the line
    (status,) = host.replies(proto.Status, since)
    assert status.mode == Mode.OPEN_LOOP and status.setpoint_deg == 40.0
    assert status.rx_overflow == 0 and status.faults == 0 and status.frames_lost == 0
    assert not host.replies(proto.ErrorReport, since)
    p = board.pulses
    p = p[p["start"] > start]
    assert len(p) >= 2 and np.all(p["width"] == pulse_cycles(40.0))


def _configure_refused(host, since: int, field: int) -> None:
    (err,) = host.replies(proto.ErrorReport, since)
    assert (err.code, err.detail) == (proto.ErrorCode.BAD_VALUE, field)
    assert not host.replies(proto.Status, since)


def test_no_configure_pulses_outside_the_hard_range(emulator_build) -> None:
    board = new_board(emulator_build)
    host = session(board)
    lo, hi = (
        host.replies(proto.Info)[-1].hard_jaw_min_deg,
        host.replies(proto.Info)[-1].hard_jaw_max_deg,
    )
    assert (lo, hi) == (21.0, 92.0)
    cal = {"adc_at_lo": 200, "adc_at_hi": 600}
    refused = [
        (proto.Configure(jaw_min=0.0, jaw_max=180.0, **cal), 7),  # widened jaw range
        (proto.Configure(jaw_min=21.0, jaw_max=120.0, **cal), 8),
        (proto.Configure(servo_us_at_0=2400, servo_us_at_180=544, **cal), 11),  # reversed
        (proto.Configure(servo_us_at_0=500, servo_us_at_180=2500, **cal), 11),  # widened map
        (proto.Configure(servo_us_at_0=1000, servo_us_at_180=2000, **cal), 11),  # shifted map
    ]
    start = board.mega.cycle
    host.send(proto.Setpoint(5.0))
    host.send(proto.SetMode(Mode.OPEN_LOOP))
    host.run(5)
    for msg, field in refused:
        since = host.ms
        host.send(msg)
        host.run(5)
        _configure_refused(host, since, field)
        host.send(proto.Setpoint(5.0))
        host.run(25)
        host.send(proto.Setpoint(175.0))
        host.run(25)
    p = board.pulses
    p = p[p["start"] > start]
    # the default range and mapping held: 5 deg pulses 21 deg, 175 deg pulses 92 deg
    assert set(p["width"].tolist()) == {pulse_cycles(21.0), pulse_cycles(92.0)}
    # a narrower range and mapping inside every limit is taken
    since = host.ms
    host.send(
        proto.Configure(jaw_min=30.0, jaw_max=80.0, servo_us_at_0=550, servo_us_at_180=2390, **cal)
    )
    host.run(5)
    assert host.replies(proto.Status, since) and not host.replies(proto.ErrorReport, since)
    start = board.mega.cycle
    for angle in (5.0, 175.0):
        host.send(proto.Setpoint(angle))
        host.run(45)
    p = board.pulses
    p = p[p["start"] > start]
    narrow = {round(2 * 550 + 0.5 + deg * 2 * 1840 / 180 - 0.5) * 8 for deg in (30.0, 80.0)}
    assert set(p["width"].tolist()) == narrow
    everything = board.pulses
    assert (
        HARD_CYCLES[0] <= everything["width"].min() and everything["width"].max() <= HARD_CYCLES[1]
    )
    assert np.all(np.diff(everything["start"].astype(np.int64)) == FRAME_CYCLES)


@pytest.mark.slow
def test_100000_fuzzed_frames(emulator_build) -> None:
    image, harness = emulator_build
    r = fuzz_image(100_000, seed=21, image=image, harness=harness)
    assert r.frames == 100_001 and r.damaged > 25_000 and r.noise_bytes > 500_000
    # 0 pulses outside the hard range, measured on the pin, with thousands of pulses at its ends
    assert r.pulses > 3000 and r.pulses_outside == 0
    assert r.pulse_us[1] == HARD_WINDOW_US[1] and r.pulse_us[0] < HARD_WINDOW_US[0] + 10
    # 0 bad frames accepted: the frames taken are exactly those sent, and the board counts them
    assert r.bad_accepted == 0 and r.board_accepted == r.delivered + 4  # + HELLO..SET_MODE
    assert r.setpoint_checks > 10_000 and r.setpoint_mismatches == 0
    # every lost command reported (FRAMES_LOST names exactly the frames not delivered)
    assert r.lost > 25_000 and r.reported_lost == r.lost
    assert r.unreported == 0 and r.false_reports == 0
    # nothing lost on the board's side of the link, and it never reset
    assert r.rx_overflow == 0 and r.tx_dropped == 0 and r.device_frames_lost == 0
    assert r.resets == 0
    assert r.refused > 10_000  # the hostile values were seen and refused


def test_an_overloaded_receive_path_counts_and_reports_what_it_loses(emulator_build) -> None:
    # CONFIGUREs back to back at the line rate: each takes the board longer to handle (~0.6 ms)
    # than to arrive (0.6 ms), so its receive ring overflows. The bytes lost are counted, their
    # frames dropped whatever their CRC, and reported lost.
    image, harness = emulator_build
    mega = Mega2560(image, harness)
    try:
        mega.set_adc(400)
        mega.run_until(50 * 16_000)
        frames = [proto.Hello()] + [
            proto.Configure(p=1.0, i=float(k), adc_at_lo=200, adc_at_hi=600, decimation=0)
            for k in range(400)
        ]
        mega.write(
            b"\x00" + b"".join(proto.encode_frame(k & 0xFF, m) for k, m in enumerate(frames))
        )
        mega.run_until(mega.rx_last_cycle + 50 * 16_000)
        mega.write(proto.encode_frame(len(frames) & 0xFF, proto.Heartbeat(7)))
        mega.run_until(mega.rx_last_cycle + 20 * 16_000)
        replies = [f.message for f in proto.FrameDecoder().feed(mega.read())]
    finally:
        mega.close()
    (status,) = [m for m in replies if isinstance(m, proto.Status) and m.echo == 7]
    answered = sum(isinstance(m, proto.Status) for m in replies) - 1
    reported = sum(m.detail for m in replies if isinstance(m, proto.ErrorReport))
    assert status.rx_overflow > 0 and status.bad_frame > 0  # counted, the frames dropped
    assert answered + reported == 400  # each CONFIGURE answered or reported lost
    assert status.frames_lost == reported and status.tx_dropped == 0

"""The compiled firmware under simavr, driven by a scripted host on emulated time: the servo pulse
it generates, the watchdog, hostile commands, a reset. Every run is deterministic: the same
frames at the same emulated instants give the same pulses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from emulator_support import FRAME_CYCLES, ends, new_board, pulse_cycles, session

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.mega2560 import CYCLES_PER_MS, EMULATED_DEVICE_ID
from gripper_env.hardware.emulator.scripted import ScriptedHost
from gripper_env.hardware.twin.rig import VirtualRig

Mode = proto.Mode
WATCHDOG_MS = 500


def test_the_image_boots_answers_and_drives_no_servo_until_an_active_mode(emulator_build) -> None:
    board = new_board(emulator_build)
    host = ScriptedHost(board)
    host.run(50)
    assert board.mega.stats()["timer1_mode"] == 14  # fast PWM, TOP = ICR1
    info = host.open_session()
    assert (info.protocol_version, info.device_id) == (proto.PROTOCOL_VERSION, EMULATED_DEVICE_ID)
    assert (info.tick_period_us, info.max_batch, info.max_payload) == (1000, 32, 240)
    host.run(40)
    assert len(board.pulses) == 0 and board.command_deg is None  # limp until an active mode
    host.send(proto.Setpoint(50.0))
    host.send(proto.SetMode(Mode.OPEN_LOOP))
    host.run(100)
    p = board.pulses
    assert len(p) >= 4
    # the pulse the datasheet's timer makes of the firmware's registers: exactly the width for
    # 50 deg at 0.5 us resolution (it was one timer tick too long), every 20 ms exactly
    assert np.all(p["width"] == pulse_cycles(50.0))
    assert np.all(np.diff(p["start"].astype(np.int64)) == FRAME_CYCLES)
    assert board.command_deg == pytest.approx(50.0, abs=0.05)
    stats = board.mega.stats()
    assert stats["pulse_faults"] == 0 and stats["rx_overruns"] == 0 and stats["log_errors"] == 0


def test_host_silence_brings_the_servo_to_the_safe_angle_within_the_watchdog_time(
    emulator_build,
) -> None:
    board = new_board(emulator_build)
    host = session(board)
    host.send(proto.Setpoint(40.0))
    host.send(proto.SetMode(Mode.OPEN_LOOP))
    for _ in range(3):
        host.run(100)
        since = host.ms
        host.send(proto.Heartbeat(7))
    silent_from = board.mega.rx_last_cycle  # the last byte of the last frame has arrived
    host.run(WATCHDOG_MS + 100)
    p = board.pulses
    late = p[p["start"] > silent_from]
    safe = late["width"] == pulse_cycles(92.0)
    assert safe.any() and np.all(late["width"][~safe.cumsum().astype(bool)] == pulse_cycles(40.0))
    first_safe = late[np.argmax(safe)]
    reached_ms = (int(first_safe["start"]) + int(first_safe["width"]) - silent_from) / CYCLES_PER_MS
    # the firmware stops at its first tick 500 ms after the last frame; the timer sends the new
    # width from its next frame (<= 20 ms), and the servo has it when that pulse ends
    assert WATCHDOG_MS <= reached_ms <= WATCHDOG_MS + 1 + 20 + 1.5, reached_ms
    assert np.all(late["width"][np.argmax(safe) :] == pulse_cycles(92.0))
    answer = host.replies(proto.Status, since)[0]  # to the last HEARTBEAT, as it arrived
    (status,) = [s for s in host.replies(proto.Status) if s.faults]
    assert status.faults == proto.Fault.WATCHDOG and status.mode == Mode.IDLE
    # on the device's own clock (micros() starts after the boot code, so it lags emulated time)
    fault_ms = (status.device_time_us - answer.device_time_us) / 1000
    assert WATCHDOG_MS <= fault_ms <= WATCHDOG_MS + 1.0, fault_ms


def _hostile(rng: np.random.Generator) -> proto.Message | bytes:
    """One message of a hostile host: out-of-range and non-finite setpoints, absurd gains and
    limits, wrong modes, stray and malformed frames. The jaw range and the servo calibration
    stay at their defaults (the firmware cannot know a servo's true pulse mapping: see
    PROTOCOL.md), so every pulse must encode an angle in [21, 92] deg."""
    big = [math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e9, -1e9, 1e-45]
    angle = [*big, -500.0, 500.0, 0.0, 180.0, -21.0, 20.9, 92.1, 200.0, 56.0]
    f = float(rng.choice([*big, 0.0, 1.0, -1.0, 50.0, -50.0, 1e4, -1e4]))
    kind = rng.integers(0, 10)
    if kind <= 2:
        return proto.Setpoint(float(rng.choice(angle)))
    if kind <= 5:
        cfg = {
            "p": f,
            "i": float(rng.choice([1e6, -1e6, 9.0, -9.0, 1e30])),
            "d": float(rng.choice([0.0, -1.0, 1.0, 1e3])),
            "n": float(rng.choice([100.0, 1999.0, 2000.0, -5.0, math.nan, 1e-30])),
            "u_min": float(rng.choice([-math.inf, -1e30, 0.0, 21.0, 50.0, math.nan, math.inf])),
            "u_max": float(rng.choice([math.inf, 1e30, 180.0, 92.0, 60.0, -math.inf])),
            "kb": float(rng.choice([1.0, 1e6, -1e6, math.inf])),
            "jaw_min": float(rng.choice([21.0, 30.0])),
            "jaw_max": float(rng.choice([92.0, 80.0])),
            "adc_at_lo": int(rng.choice([80, 0, 1023, 300])),
            "adc_at_hi": int(rng.choice([349, 1019, 82])),
            "anti_windup": int(rng.integers(0, 4)),
            "sign": int(rng.choice([1, -1, 0, 127])),
            "d_on_meas": int(rng.integers(0, 3)),
            "decimation": int(rng.choice([0, 1, 7, 1000, 1001])),
            "telemetry_batch": int(rng.choice([1, 10, 32, 33])),
        }
        return proto.Configure(**cfg)
    if kind == 6:
        return proto.SetMode(int(rng.choice([0, 1, 2, 2, 2, 3, 255])))
    if kind == 7:  # CRC-valid frames of any type and length
        payload = rng.integers(0, 256, int(rng.integers(0, 60)), dtype=np.uint8).tobytes()
        return proto.encode_raw_frame(int(rng.integers(0, 256)), int(rng.integers(0, 256)), payload)
    if kind == 8:
        return rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
    return proto.Heartbeat(int(rng.integers(0, 2**32)))


def test_hostile_setpoints_and_gains_never_pulse_outside_the_jaw_range(emulator_build) -> None:
    board = new_board(emulator_build)
    host = session(board, p=1.0, i=9.0, d=-0.001)
    host.send(proto.Setpoint(50.0))
    host.send(proto.SetMode(Mode.CLOSED_LOOP))
    host.run(50)
    rng = np.random.default_rng(20260112)
    for k in range(400):
        msg = _hostile(rng)
        if isinstance(msg, bytes):
            host.send_raw(msg)
        else:
            host.send(msg)
        if k % 50 == 49:  # now and then the host insists: acknowledge faults, closed loop again
            host.send(proto.SetMode(Mode.IDLE))
            host.send(proto.SetMode(Mode.CLOSED_LOOP))
        host.run(int(rng.integers(1, 12)))
    host.run(100)
    p = board.pulses
    assert len(p) > 100
    # every pulse, at every emulated instant it was high, encodes an angle in the jaw range
    assert p["width"].min() >= pulse_cycles(21.0) and p["width"].max() <= pulse_cycles(92.0)
    assert np.all(np.diff(p["start"].astype(np.int64)) == FRAME_CYCLES)  # no runt, no gap
    s = host.samples()
    on = ~np.isnan(s.command_deg)
    assert np.all((s.command_deg[on] >= 21.0) & (s.command_deg[on] <= 92.0))
    stats = board.mega.stats()
    assert stats["state"] in (2, 3) and stats["resets"] == 0  # never crashed nor reset
    assert stats["pulse_faults"] == 0 and stats["log_errors"] == 0
    refused = [e for e in host.replies(proto.ErrorReport) if e.code == proto.ErrorCode.BAD_VALUE]
    assert len(refused) > 50  # the hostile values were seen and refused, not ignored
    # the closed loop ran with hostile accepted gains too: the clamp held, not the luck of the gains
    assert np.any(s.flags & proto.SampleFlag.SATURATED)


def test_a_reset_mid_run_cuts_one_pulse_then_the_servo_is_limp_until_the_host_reconnects(
    emulator_build,
) -> None:
    board = new_board(emulator_build)
    host = session(board, p=1.0, i=9.0, d=-0.001)
    host.send(proto.Setpoint(40.0))
    host.send(proto.SetMode(Mode.CLOSED_LOOP))
    host.run(400)
    # reset half-way through a pulse (the worst instant): the pin is released mid-pulse
    last = board.pulses[-1]
    mid = int(last["start"]) + FRAME_CYCLES + int(last["width"]) // 2
    board.mega.run_until(mid)
    board.reset()
    reset_cycle = board.mega.cycle
    host.run(200)
    p = board.pulses
    after = p[p["start"] >= reset_cycle - FRAME_CYCLES]
    assert len(after) == 1 and int(after["width"][0]) < pulse_cycles(21.0)  # the runt
    assert board.mega.stats()["pulse_faults"] == 1 and board.command_deg is None  # limp
    # the firmware restarted: no session, so the host's next frame is refused with NO_SESSION
    since = host.ms
    host.send(proto.Heartbeat(1))
    host.run(10)
    (err,) = host.replies(proto.ErrorReport, since)
    assert err.code == proto.ErrorCode.NO_SESSION
    # the host reconnects: HELLO, CONFIGURE, closed loop; pulses resume within one frame
    lo, hi = (round(c) for c in board.rig.true_calibration)
    host.open_session(proto.Configure(p=1.0, i=9.0, d=-0.001, adc_at_lo=lo, adc_at_hi=hi))
    host.send(proto.Setpoint(40.0))
    start = board.mega.cycle
    host.send(proto.SetMode(Mode.CLOSED_LOOP))
    host.run(1500, heartbeat_ms=200)
    resumed = board.pulses[board.pulses["start"] >= start]
    assert (int(resumed["start"][0]) - start) / CYCLES_PER_MS <= 21.0
    assert resumed["width"].min() >= pulse_cycles(21.0)
    assert resumed["width"].max() <= pulse_cycles(92.0)
    assert abs(board.rig.position_deg - 40.0) < 2.0  # regulating again


@pytest.mark.parametrize("flood_bytes", [4096])
def test_line_noise_is_rejected_and_the_loop_keeps_its_period(emulator_build, flood_bytes) -> None:
    board = new_board(emulator_build)
    host = session(board, p=1.0, i=9.0, d=-0.001)
    host.send(proto.Setpoint(40.0))
    host.send(proto.SetMode(Mode.CLOSED_LOOP))
    host.run(300)
    host.send_raw(np.random.default_rng(4).integers(0, 256, flood_bytes, dtype=np.uint8).tobytes())
    host.run(100)  # 4 KiB take ~45 ms on the line
    since = host.ms
    host.send_raw(b"\x00")
    host.send(proto.Heartbeat(99))
    host.run(20)
    (status,) = host.replies(proto.Status, since)
    assert status.echo == 99 and status.faults == 0 and status.mode == Mode.CLOSED_LOOP
    assert status.bad_frame + status.bad_crc > 0
    # the control ticks kept coming: one telemetry sample per millisecond throughout
    s = host.samples()
    assert np.all(np.round(np.diff(s.t_us) / 1000) == 1)
    assert np.all(np.diff(board.pulses["start"].astype(np.int64)) == FRAME_CYCLES)
    assert ends(board.pulses)[-1] > board.mega.cycle - FRAME_CYCLES - 3 * CYCLES_PER_MS


def test_the_rig_drives_the_pulse_train_not_the_presets_command_path() -> None:
    rig = VirtualRig("test2", "actual", pulse_train=True)
    assert rig.disturbance.command.quantization == "none"
    assert rig.disturbance.command.refresh_period_s == 0.0
    assert rig.disturbance.friction.model == "choudhury"  # the rest of the preset stays

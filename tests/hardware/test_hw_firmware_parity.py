"""gripper_core.h (host build) against the Python twin: bytes on the wire and PID numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hw_support import field_tokens, messages
from hypothesis import given, settings
from hypothesis import strategies as st

from gripper_env.hardware import protocol as proto
from gripper_env.model.pid import PID, PIDGains, PIDOptions, pid_update


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_crc_and_cobs_agree(harness, data: bytes) -> None:
    hexed = data.hex() or "-"
    assert int(harness("crc", hexed), 16) == proto.crc16_ccitt_false(data)
    encoded = proto.cobs_encode(data)
    assert harness("cobs_enc", hexed) == (encoded.hex() or "-")
    assert harness("cobs_dec", encoded.hex()) == (data.hex() or "-")


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=1, max_size=300))
def test_cobs_decoders_agree_on_arbitrary_input(harness, data: bytes) -> None:
    data = data.replace(b"\x00", b"\x07")  # the stream decoder never passes a zero byte
    try:
        expected = proto.cobs_decode(data).hex() or "-"
    except proto.CobsError:
        expected = "ERR"
    assert harness("cobs_dec", data.hex()) == expected


@settings(max_examples=400, deadline=None)
@given(messages, st.integers(0, 255))
def test_cpp_decodes_python_frames_and_reencodes_identically(harness, msg, seq: int) -> None:
    frame = proto.encode_frame(seq, msg)
    answer = harness("reencode", frame.hex()).split()
    assert answer[0] == "OK", answer
    assert int(answer[1]) == seq and int(answer[2]) == msg.TYPE
    assert answer[3] == frame.hex()
    # Field by field, so a consistent swap in the C++ decoder and encoder cannot hide.
    assert answer[4:] == field_tokens(msg)


@settings(max_examples=400, deadline=None)
@given(messages, st.integers(0, 255))
def test_cpp_encodes_the_python_bytes(harness, msg, seq: int) -> None:
    frame = bytes.fromhex(harness("encode", msg.TYPE, seq, *field_tokens(msg)))
    assert frame == proto.encode_frame(seq, msg)
    got_seq, decoded = proto.decode_frame(frame)
    assert got_seq == seq and decoded.encode() == msg.encode()


def test_cpp_stream_decoder_rejects_like_python(harness) -> None:
    good = proto.encode_frame(1, proto.Setpoint(40.0))
    raw = bytearray(proto.cobs_decode(good[:-1]))
    raw[2] ^= 1
    assert harness("reencode", (proto.cobs_encode(bytes(raw)) + b"\x00").hex()) == "ERR bad_crc"
    assert harness("reencode", (proto.cobs_encode(b"\x01\x02") + b"\x00").hex()) == "ERR truncated"
    assert harness("reencode", (b"\x01" * 300 + b"\x00").hex()) == "ERR oversized"
    assert harness("reencode", "0501020300") == "ERR bad_cobs"
    assert harness("reencode", proto.encode_raw_frame(0, 0x42, b"").hex()) == "ERR unknown_type"
    bad_len = proto.encode_raw_frame(0, proto.SetMode.TYPE, b"\x01\x02")
    assert harness("reencode", bad_len.hex()) == "ERR bad_payload"


# ---- PID parity -------------------------------------------------------------------------------

DT = 1e-3

# (P, I, D, N, u_min, u_max, aw_mode, kb, sign, d_on_meas)
GAIN_SETS = {
    "paper_untuned_tf": (-0.4, 7.0, -0.045, 100.0, -math.inf, math.inf, 0, 1.0, 1.0, 0),
    "paper_tuned_tf_clamp": (1.0, 9.0, -0.001, 100.0, 21.0, 92.0, 1, 1.0, 1.0, 0),
    "paper_hw_sign_minus": (-0.5, -3.6, 0.000186, 100.0, 21.0, 92.0, 1, 1.0, -1.0, 0),
    "paper_hw_untuned_backcalc": (-0.3, -5.0, -0.0005, 100.0, 21.0, 92.0, 2, 5.0, -1.0, 1),
    "aggressive_saturating_none": (8.0, 40.0, 0.02, 500.0, 30.0, 80.0, 0, 1.0, 1.0, 0),
    "aggressive_saturating_clamp": (8.0, 40.0, 0.02, 500.0, 30.0, 80.0, 1, 1.0, 1.0, 1),
    "aggressive_saturating_backcalc": (8.0, 40.0, 0.02, 500.0, 30.0, 80.0, 2, 20.0, 1.0, 0),
    "negative_everything_d_on_meas": (-2.0, -15.0, -0.05, 1500.0, 0.0, 100.0, 1, 1.0, -1.0, 1),
    "pure_integral_backcalc_sign_minus": (0.0, 12.0, 0.0, 100.0, 21.0, 92.0, 2, 3.0, -1.0, 0),
}


def _inputs(seed: int, n: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """Grip/un-grip steps and a ramp as reference; a lagging, noisy, quantized measurement."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    r = np.where((k // 150) % 2 == 0, 92.0, 21.0)
    r[450:] = np.linspace(21.0, 92.0, n - 450)
    y = np.empty(n)
    level = 92.0
    for j in range(n):
        level += 0.05 * (r[j] - level) + rng.normal(0, 0.3)
        y[j] = round(level / 0.25) * 0.25
    return r, y


def _run_python(gains: tuple, r: np.ndarray, y: np.ndarray, state0: tuple[float, float]):
    p, i, d, n, u_min, u_max, aw, kb, sign, dmeas = gains
    state = np.array(state0, dtype=np.float64)
    out = []
    for rk, yk in zip(r, y, strict=True):
        u, v = pid_update(
            float(rk), float(yk), p, i, d, n, DT, u_min, u_max, aw, kb, sign, dmeas, state
        )
        out += [u, v]
    return np.array(out), state


def _run_cpp(h, gains: tuple, r: np.ndarray, y: np.ndarray, state0: tuple[float, float]):
    ry = [float(x).hex() for pair in zip(r, y, strict=True) for x in pair]
    args = [float(DT).hex(), *(float(g).hex() for g in gains), *(float(s).hex() for s in state0)]
    answer = h("pid", *args, len(r), *ry).split()
    values = np.array([float.fromhex(t) for t in answer])
    return values[:-2], values[-2:]


@pytest.mark.parametrize("name", sorted(GAIN_SETS))
def test_pid_matches_python_pid_update(harness, name: str) -> None:
    gains = GAIN_SETS[name]
    for seed, state0 in [(0, (0.0, 0.0)), (1, (92.0, -92.0 * gains[8]))]:
        r, y = _inputs(seed)
        expected, state = _run_python(gains, r, y, state0)
        got, got_state = _run_cpp(harness, gains, r, y, state0)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(got_state, state, rtol=0, atol=1e-6)
        if np.isfinite(gains[4]):
            u = expected[0::2]
            assert np.any(u == gains[4]) or np.any(u == gains[5]), "case never saturates"


def test_pid_matches_python_pid_class_after_reset(harness) -> None:
    gains = GAIN_SETS["paper_hw_sign_minus"]
    pid = PID(
        PIDGains(P=gains[0], I=gains[1], D=gains[2], N=gains[3]),
        dt_s=DT,
        options=PIDOptions(output_limits=(21.0, 92.0), sign=-1, derivative_on="measurement"),
    )
    pid.reset(u0=92.0, y0=90.0)
    r, y = _inputs(3)
    state0 = (float(pid.state[0]), float(pid.state[1]))
    expected = [pid.step(rk, yk) for rk, yk in zip(r, y, strict=True)]
    cpp_gains = (*gains[:4], 21.0, 92.0, 1, 1.0, -1.0, 1)
    got, _ = _run_cpp(harness, cpp_gains, r, y, state0)
    np.testing.assert_allclose(got[0::2], expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["paper_tuned_tf_clamp", "aggressive_saturating_backcalc"])
def test_board_float_pid_stays_close_to_double(harness, harness_f32, name: str) -> None:
    # The board computes in float32; over a few thousand ticks it must not drift visibly.
    gains = GAIN_SETS[name]
    r, y = _inputs(5, n=3000)
    reference, _ = _run_cpp(harness, gains, r, y, (92.0, 0.0))
    board, _ = _run_cpp(harness_f32, gains, r, y, (92.0, 0.0))
    np.testing.assert_allclose(board[0::2], reference[0::2], rtol=0, atol=0.01)


# ---- the grasp mode --------------------------------------------------------------------------

# (squeeze, push, short, still, dwell ticks)
GRASP = (1.0, 5.0, 0.5, 1.0, 100.0)


def _grasp_inputs(seed: int, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """Close on an object at 40 deg (the reference 38, then 30), open again at 3 s: the jaw
    follows the reference but stops at the object; noisy, quantised like the ADC."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    r = np.where(k < 200, 92.0, np.where(k < 1800, 38.0, np.where(k < 3000, 30.0, 92.0)))
    y = np.empty(n)
    level = 92.0
    for j in range(n):
        level = max(40.0, level + 0.03 * (r[j] - level))
        y[j] = round((level + rng.normal(0, 0.4)) / 0.264) * 0.264
    return r, y


def _run_python_grasp(gains: tuple, r: np.ndarray, y: np.ndarray, state0: tuple) -> tuple:
    p, i, d, n, u_min, u_max, aw, kb, sign, dmeas = gains
    state = np.array(state0, dtype=np.float64)
    out, held = [], []
    for rk, yk in zip(r, y, strict=True):
        u, v = pid_update(
            float(rk), float(yk), p, i, d, n, DT, u_min, u_max, aw, kb, sign, dmeas, state, 1,
            *GRASP,
        )  # fmt: skip
        out += [u, v]
        held.append(state[2])
    return np.array(out), np.array(held), state


def _run_cpp_grasp(h, gains: tuple, r: np.ndarray, y: np.ndarray, state0: tuple) -> tuple:
    ry = [float(x).hex() for pair in zip(r, y, strict=True) for x in pair]
    args = [float(DT).hex(), *(float(g).hex() for g in (*gains, *GRASP)),
            *(float(s).hex() for s in state0)]  # fmt: skip
    values = np.array([float.fromhex(t) for t in h("pid_grasp", *args, len(r), *ry).split()])
    per = values[:-6].reshape(-1, 3)
    return per[:, :2].ravel(), per[:, 2], values[-6:]


@pytest.mark.parametrize(
    "name", ["paper_tuned_tf_clamp", "paper_hw_sign_minus", "aggressive_saturating_backcalc"]
)
def test_grasp_mode_matches_python_pid_update(harness, name: str) -> None:
    gains = GAIN_SETS[name]
    r, y = _grasp_inputs(7)
    state0 = (92.0, 0.0, 0.0, 92.0, 0.0, 92.0)  # PID.reset(u0=92, y0=92)
    expected, held, state = _run_python_grasp(gains, r, y, state0)
    got, got_held, got_state = _run_cpp_grasp(harness, gains, r, y, state0)
    np.testing.assert_array_equal(got_held, held)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got_state, state, rtol=0, atol=1e-6)
    # the case grasps (closing), and the opening at 3 s lets go
    assert np.any(held == -1.0) and held[-1] == 0.0


def test_board_float_grasp_mode_holds_like_double(harness, harness_f32) -> None:
    gains = GAIN_SETS["paper_tuned_tf_clamp"]
    r, y = _grasp_inputs(8)
    state0 = (92.0, 0.0, 0.0, 92.0, 0.0, 92.0)
    reference, held, _ = _run_cpp_grasp(harness, gains, r, y, state0)
    board, board_held, _ = _run_cpp_grasp(harness_f32, gains, r, y, state0)
    # the same grasp within a tick or two (float32 may cross a threshold a sample apart)
    onset, board_onset = np.argmax(held == -1), np.argmax(board_held == -1)
    assert held[onset] == -1 and abs(int(onset) - int(board_onset)) <= 2
    both = (held == -1) & (board_held == -1)
    np.testing.assert_allclose(board[0::2][both], reference[0::2][both], rtol=0, atol=0.01)

"""Fuzzed host traffic against the compiled firmware image: :func:`fuzz_image`.

A seeded stream of host frames (setpoints of any value, mode changes, configurations that are
mostly hostile: widened jaw ranges, reversed and shifted pulse mappings, non-finite gains;
heartbeats, ESTOPs, CRC-valid frames of unknown types and wrong lengths) goes to the image under
simavr (:class:`~gripper_env.hardware.emulator.mega2560.Mega2560`, driven directly, at the
emulation's
full speed). About one frame in three is damaged on the way: bit flips (one to three), a byte
replaced, dropped or repeated, two bytes swapped, the frame cut short, its delimiter lost (it
merges with the next), or stray bytes; now and then a burst of line noise up to 2 KiB comes
between two frames, and its last byte is a delimiter, so the next frame must arrive intact.

What is measured against independent truth:

* **pulses**: every servo pulse Timer1 generated, against the hard window the datasheet mapping
  (544/2400 us) gives the hard jaw range 21-92 deg (:data:`HARD_WINDOW_US`);
* **bad frames accepted**: the frames the protocol's decoder
  (:class:`~gripper_env.hardware.protocol.FrameSplitter`, the spec's, checked against the
  firmware's byte for byte in ``tests/hardware``) takes from the damaged stream, compared with the
  frames sent under the same sequence number; the board's own count (``STATUS.frames_ok``) must
  equal the decoder's, and the setpoint the board reports (``STATUS.setpoint_deg``) must be at
  every answer the last one delivered intact;
* **lost commands**: the frames not delivered, against those the board reported missing (ERROR
  ``FRAMES_LOST``); a host sends them again or knows they were superseded
  (:mod:`~gripper_env.hardware.host.command_log`);
* the link's health: bytes lost on the receive path (``STATUS.rx_overflow``), device frames
  dropped for lack of transmit buffer, or lost on the way back.

Frames are paced so the board's answers fit the line back (the host of a real rig waits for
answers); a mode change, heartbeat or configuration every few frames keeps it busy.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.mega2560 import CYCLES_PER_MS, CYCLES_PER_US, Mega2560

__all__ = ["HARD_WINDOW_US", "FuzzResult", "fuzz_image"]

# 21 and 92 deg under the datasheet mapping 544 + deg * (2400 - 544) / 180 us, to the 0.5 us tick
HARD_WINDOW_US = (
    round(2 * (544 + 21 * 1856 / 180)) / 2,
    round(2 * (544 + 92 * 1856 / 180)) / 2,
)
ADC_COUNTS = 400  # the potentiometer, mid-range (the fuzz's configurations calibrate 200..600)
# A frame starts this long after the previous one began (or when the line is free after noise):
# a setpoint stream's pace, and a host that waits for the answer to a command before the next
# (the board takes ~0.4 ms to handle a command and send its answer; faster, it would fall behind
# and its receive buffer overflow: counted and reported, see test_hw_emulated_fuzz)
FRAME_SPACING_US = 330
ANSWERED_SPACING_US = 1000
CORRUPT_P = 0.3
NOISE_P = 0.01
_WILD = [math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e9, -1e9, 0.0, -0.0, 1e-45]


@dataclass
class FuzzResult:
    """What :func:`fuzz_image` measured (see the module docstring).

    Attributes
    ----------
    frames : int
        Host frames sent.
    damaged : int
        Of them, damaged on the way by the fuzz.
    delivered : int
        Frames the protocol's decoder takes from the stream sent.
    bad_accepted : int
        Delivered frames whose bytes differ from the frame sent under that sequence number.
    board_accepted : int
        Host frames the board counted valid (``STATUS.frames_ok``).
    lost : int
        Frames sent and not delivered.
    reported_lost : int
        Sequence numbers the board reported missing.
    unreported : int
        Lost frames the board did not report.
    false_reports : int
        Reported frames that were delivered.
    setpoint_checks, setpoint_mismatches : int
        Answers whose ``setpoint_deg`` was compared with the last setpoint delivered, and those
        that differed.
    pulses, pulses_outside : int
        Servo pulses, and those outside :data:`HARD_WINDOW_US`.
    pulse_us : (float, float)
        The narrowest and widest pulse (us).
    """

    frames: int = 0
    damaged: int = 0
    delivered: int = 0
    bad_accepted: int = 0
    board_accepted: int = 0
    lost: int = 0
    reported_lost: int = 0
    unreported: int = 0
    false_reports: int = 0
    setpoint_checks: int = 0
    setpoint_mismatches: int = 0
    pulses: int = 0
    pulses_outside: int = 0
    pulse_us: tuple[float, float] = (math.nan, math.nan)
    noise_bytes: int = 0
    refused: int = 0
    rx_overflow: int = 0
    tx_dropped: int = 0
    device_frames_lost: int = 0
    overruns: int = 0
    resets: int = 0
    emulated_s: float = 0.0
    damage_kinds: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The fields as plain JSON values."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(self).items()}


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def _configure(rng: np.random.Generator) -> proto.Configure:
    """Mostly hostile: widened or shifted jaw ranges, reversed or shifted pulse mappings,
    non-finite gains; one in four inside every limit (a narrower range or mapping)."""
    if rng.random() < 0.25:
        lo = float(rng.uniform(21.0, 60.0))
        return proto.Configure(
            p=float(rng.uniform(-5, 5)),
            i=float(rng.uniform(-20, 20)),
            d=float(rng.uniform(-0.01, 0.01)),
            jaw_min=lo,
            jaw_max=float(rng.uniform(lo + 1.0, 92.0)),
            adc_at_lo=200,
            adc_at_hi=600,
            servo_us_at_0=int(rng.integers(544, 560)),
            servo_us_at_180=int(rng.integers(2380, 2401)),
            anti_windup=int(rng.integers(0, 3)),
            sign=int(rng.choice([1, -1])),
            decimation=int(rng.choice([0, 10, 100])),
        )
    wide = [(0.0, 180.0), (10.0, 92.0), (21.0, 120.0), (-5.0, 200.0), (92.0, 21.0)]
    mapping = [(2400, 544), (500, 2500), (544, 2600), (400, 2600), (1000, 2000), (2600, 400)]
    jaw = wide[rng.integers(len(wide))] if rng.random() < 0.6 else (21.0, 92.0)
    us = mapping[rng.integers(len(mapping))] if rng.random() < 0.6 else (544, 2400)
    return proto.Configure(
        p=float(rng.choice([*_WILD, 1.0, -3.0])),
        i=float(rng.choice([9.0, -9.0, 1e6, math.nan])),
        d=float(rng.choice([0.0, -0.001, 1e3])),
        n=float(rng.choice([100.0, 1999.0, 2000.0, -5.0, math.nan])),
        u_min=float(rng.choice([-math.inf, 0.0, 21.0, math.nan])),
        u_max=float(rng.choice([math.inf, 180.0, 92.0, -math.inf])),
        jaw_min=jaw[0],
        jaw_max=jaw[1],
        adc_at_lo=int(rng.choice([200, 0, 1023])),
        adc_at_hi=int(rng.choice([600, 205, 1021])),
        servo_us_at_0=us[0],
        servo_us_at_180=us[1],
        decimation=int(rng.choice([0, 10, 1001])),
        anti_windup=int(rng.integers(0, 4)),
        sign=int(rng.choice([1, -1, 0])),
        telemetry_batch=int(rng.choice([10, 32, 0, 33])),
    )


def _message(rng: np.random.Generator, seq: int) -> bytes:
    """One host frame, whole and CRC-valid; all but SETPOINT are answered (STATUS or ERROR)."""
    kind = rng.random()
    msg: proto.Message
    if kind < 0.45:
        if rng.random() < 0.7:
            msg = proto.Setpoint(float(rng.uniform(-100.0, 300.0)))
        else:
            msg = proto.Setpoint(float(rng.choice(_WILD)))
    elif kind < 0.63:
        msg = proto.SetMode(int(rng.choice([0, 1, 1, 2, 2, 3])))
    elif kind < 0.73:
        msg = proto.Heartbeat(int(rng.integers(0, 2**32)))
    elif kind < 0.83:
        msg = _configure(rng)
    elif kind < 0.85:
        msg = proto.Estop()
    else:  # CRC-valid frames of a wrong length, an unknown or a device type
        type_id = int(rng.choice([2, 3, 4, 6, 7, 0, 9, 0x42, 0x81, 0x83]))
        payload = rng.integers(0, 256, int(rng.integers(0, 12)), dtype=np.uint8).tobytes()
        return proto.encode_raw_frame(seq, type_id, payload)
    return proto.encode_frame(seq, msg)


_KINDS: tuple[str, ...] = (
    "bit flips",
    "byte replaced",
    "byte dropped",
    "byte repeated",
    "bytes swapped",
    "cut",
    "delimiter lost",
    "stray bytes",
)


def _damage(rng: np.random.Generator, frame: bytes) -> tuple[bytes, str]:
    """The frame as a noisy line delivers it, and the kind of damage."""
    b = bytearray(frame)
    kind = _KINDS[int(rng.integers(len(_KINDS)))]
    body = len(b) - 1  # the delimiter is the last byte
    k = int(rng.integers(body))
    if kind == "bit flips":
        for _ in range(int(rng.integers(1, 4))):
            j = int(rng.integers(body))
            b[j] ^= 1 << int(rng.integers(8))
    elif kind == "byte replaced":
        b[k] = (b[k] + int(rng.integers(1, 256))) & 0xFF
    elif kind == "byte dropped":
        del b[k]
    elif kind == "byte repeated":
        b.insert(k, b[k])
    elif kind == "bytes swapped":
        j = min(k + 1, body - 1)
        if b[k] == b[j]:
            b[k] ^= 0x5A
        b[k], b[j] = b[j], b[k]
    elif kind == "cut":
        b = b[:k] + b"\x00"
    elif kind == "delimiter lost":
        b = b[:-1]
    else:
        b[k:k] = rng.integers(1, 256, int(rng.integers(1, 6)), dtype=np.uint8).tobytes()
    return bytes(b), kind


class _Replies:
    """The board's frames as they come back, and the checks made on them."""

    def __init__(self) -> None:
        self.decoder = proto.FrameDecoder()
        self.reported: set[int] = set()  # indices into the frames sent
        self.statuses: list[proto.Status] = []
        self.refused = 0

    def feed(self, data: bytes, index_of_seq: Any) -> None:
        for frame in self.decoder.feed(data):
            msg = frame.message
            if isinstance(msg, proto.ErrorReport):
                if msg.code == proto.ErrorCode.FRAMES_LOST:
                    for k in range(msg.detail):
                        self.reported.add(index_of_seq((msg.seq + k) & 0xFF))
                else:
                    self.refused += 1
            elif isinstance(msg, proto.Status):
                self.statuses.append(msg)


def fuzz_image(
    n_frames: int = 100_000,
    seed: int = 0,
    *,
    image: str | os.PathLike[str] | None = None,
    harness: str | os.PathLike[str] | None = None,
    spacing_answered: int = ANSWERED_SPACING_US,
) -> FuzzResult:
    """Send ``n_frames`` fuzzed host frames to the image and measure (module docstring).

    Parameters
    ----------
    n_frames : int
        Host frames to send (each sequence number is used once, wrapping at 256).
    seed : int
        Seed of the fuzz (the run is deterministic: emulated time is the only clock).
    image, harness : path, optional
        The firmware image and the simavr harness (:class:`Mega2560`'s defaults).
    spacing_answered : int
        Microseconds from a frame the board answers to the next (:data:`ANSWERED_SPACING_US`;
        less overloads the board).

    Returns
    -------
    FuzzResult
    """
    rng = np.random.default_rng(seed)
    mega = Mega2560(image, harness)
    out = FuzzResult()
    replies = _Replies()
    sent: list[bytes] = []  # the intact frames, by index
    stream = bytearray()  # every byte put on the line, for the protocol's decoder
    first_index = [0] * 256  # a sequence number's latest frame index

    def index_of_seq(seq: int) -> int:
        return first_index[seq]

    pulses: list[np.ndarray] = []

    def put(data: bytes) -> None:
        stream.extend(data)
        mega.write(data)

    def drain() -> None:
        replies.feed(mega.read(), index_of_seq)
        p = mega.read_pulses()
        if len(p):
            pulses.append(p["width"].astype(np.int64))

    try:
        mega.set_adc(ADC_COUNTS)
        mega.run_ms(50)  # boot
        seq = 0
        opening = [
            proto.Hello(),
            proto.Configure(p=1.0, i=9.0, d=-0.001, adc_at_lo=200, adc_at_hi=600, decimation=10),
            proto.Setpoint(56.0),
            proto.SetMode(proto.Mode.OPEN_LOOP),
        ]
        put(b"\x00")
        for msg in opening:
            frame = proto.encode_frame(seq, msg)
            first_index[seq] = len(sent)
            sent.append(frame)
            put(frame)
            seq = (seq + 1) & 0xFF
            mega.run_ms(2)
        start = mega.cycle
        next_at = mega.cycle
        for i in range(n_frames):
            if rng.random() < NOISE_P:  # line noise, ended by a delimiter
                noise = rng.integers(0, 256, int(rng.integers(16, 2048)), dtype=np.uint8)
                put(noise.tobytes() + b"\x00")
                out.noise_bytes += len(noise) + 1
            frame = _message(rng, seq)
            first_index[seq] = len(sent)
            sent.append(frame)
            spacing = FRAME_SPACING_US
            if i == n_frames - 1 or rng.random() >= CORRUPT_P:
                put(frame)
                if frame[2] != proto.Setpoint.TYPE or len(frame) != 10:
                    spacing = spacing_answered
            else:
                damaged, kind = _damage(rng, frame)
                out.damage_kinds[kind] = out.damage_kinds.get(kind, 0) + 1
                out.damaged += 1
                put(damaged)
            seq = (seq + 1) & 0xFF
            next_at = max(next_at + spacing * CYCLES_PER_US, mega.rx_last_cycle)
            mega.run_until(next_at)
            if i % 64 == 63:
                drain()
        # a last heartbeat reveals trailing losses; its answer closes the books
        put(b"\x00")
        final = proto.encode_frame(seq, proto.Heartbeat(0xF00D))
        first_index[seq] = len(sent)
        sent.append(final)
        put(final)
        mega.run_until(mega.rx_last_cycle + 30 * CYCLES_PER_MS)
        drain()
        out.emulated_s = (mega.cycle - start) / (1000 * CYCLES_PER_MS)
        out.resets = mega.stats()["resets"]
    finally:
        mega.close()

    out.frames = len(sent) - len(opening)
    _judge_delivery(out, sent, bytes(stream), replies, len(opening))
    widths = np.concatenate(pulses) if pulses else np.zeros(0, np.int64)
    lo, hi = (round(us * 2) * CYCLES_PER_US // 2 for us in HARD_WINDOW_US)
    out.pulses = len(widths)
    out.pulses_outside = int(np.sum((widths < lo) | (widths > hi)))
    if len(widths):
        out.pulse_us = (widths.min() / CYCLES_PER_US, widths.max() / CYCLES_PER_US)
    final_status = replies.statuses[-1]
    out.board_accepted = final_status.frames_ok
    out.rx_overflow = final_status.rx_overflow
    out.tx_dropped = final_status.tx_dropped
    out.overruns = final_status.overruns
    out.refused = replies.refused
    s = replies.decoder.stats
    out.device_frames_lost = s.lost + s.rejected
    return out


def _judge_delivery(
    out: FuzzResult, sent: list[bytes], stream: bytes, replies: _Replies, opening: int
) -> None:
    """Which frames the protocol's decoder takes from the stream, against what was sent; the
    board's loss reports and its setpoint against them."""
    splitter = proto.FrameSplitter()
    delivered: list[int] = []  # indices of frames sent, in order
    raw_sent = [proto.cobs_decode(f[:-1]) for f in sent]
    k = 0
    for seq, type_id, payload, _gap in splitter.split(stream):
        raw = bytes((seq, type_id)) + payload
        # the next frame sent under this sequence number (at most 256 frames on)
        j = next((m for m in range(k, min(k + 256, len(sent))) if raw_sent[m][0] == seq), None)
        if j is None or raw_sent[j][:-2] != raw:
            out.bad_accepted += 1
            continue
        delivered.append(j)
        k = j + 1
    is_delivered = np.zeros(len(sent), bool)
    is_delivered[delivered] = True
    out.delivered = int(is_delivered[opening:].sum())
    lost = set(np.flatnonzero(~is_delivered).tolist())
    out.lost = len(lost)
    out.reported_lost = len(replies.reported)
    out.unreported = len(lost - replies.reported)
    out.false_reports = len(replies.reported - lost)
    # the board's setpoint at each answer: the last SETPOINT delivered before the answered frame
    setpoint = math.nan
    expected: dict[int, float] = {}
    for j in delivered:
        if raw_sent[j][1] == proto.Setpoint.TYPE and len(raw_sent[j]) == 8:
            (value,) = struct.unpack_from("<f", raw_sent[j], 2)
            if math.isfinite(value):
                setpoint = _f32(value)
        expected[j] = setpoint
    pos = 0
    seqs = [raw_sent[j][0] for j in delivered]
    for status in replies.statuses:
        m = next((q for q in range(pos, len(delivered)) if seqs[q] == status.last_rx_seq), None)
        if m is None:
            continue
        pos = m
        want = expected[delivered[m]]
        out.setpoint_checks += 1
        same = (math.isnan(want) and math.isnan(status.setpoint_deg)) or want == status.setpoint_deg
        out.setpoint_mismatches += not same

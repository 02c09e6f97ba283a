"""The device -> host messages (reports): INFO, TELEMETRY, STATUS and ERROR."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, fields
from typing import ClassVar, Self

from gripper_env.hardware.protocol.constants import (
    CDEG_NONE,
    MAX_PAYLOAD,
    PROTOCOL_VERSION,
    TELEMETRY_MAX_SAMPLES,
    Mode,
    SampleFlag,
)
from gripper_env.hardware.protocol.errors import PayloadLengthError
from gripper_env.hardware.protocol.messages import FixedMessage, Message
from gripper_env.hardware.protocol.wire import check_count, check_field

__all__ = [
    "SAMPLE_STRUCT",
    "TELEMETRY_HEADER_STRUCT",
    "ErrorReport",
    "Info",
    "Status",
    "Telemetry",
    "TelemetrySample",
]


@dataclass(frozen=True)
class Info(FixedMessage):
    """Device -> host, type 0x81: answer to a matching HELLO (29 bytes).

    Parameters
    ----------
    protocol_version : int
        Protocol version of the firmware (u16).
    fw_major, fw_minor, fw_patch : int
        Firmware version (u8 each).
    device_id : int
        Board id from EEPROM bytes 0-3 (u32), 0xFFFFFFFF if never written.
    tick_period_us : int
        Control period (us, u16).
    max_batch : int
        Largest ``telemetry_batch`` the firmware accepts (u8).
    max_payload : int
        Largest payload in bytes (u8).
    hard_jaw_min_deg, hard_jaw_max_deg : float
        The hard jaw range compiled into the image (deg, f32): no CONFIGURE can move the jaw
        outside it.
    hard_pulse_min_us, hard_pulse_max_us : float
        The hard pulse window (us, f32, 0.5 us steps): every servo pulse lies in it; the pulses
        of the hard jaw range under the servo mapping the image was built for.
    """

    TYPE: ClassVar[int] = 0x81
    _FORMAT: ClassVar[str] = "HBBBIHBBffff"
    protocol_version: int = PROTOCOL_VERSION
    fw_major: int = 0
    fw_minor: int = 0
    fw_patch: int = 0
    device_id: int = 0xFFFFFFFF
    tick_period_us: int = 1000
    max_batch: int = TELEMETRY_MAX_SAMPLES
    max_payload: int = MAX_PAYLOAD
    hard_jaw_min_deg: float = 21.0
    hard_jaw_max_deg: float = 92.0
    hard_pulse_min_us: float = 760.5
    hard_pulse_max_us: float = 1492.5


@dataclass(frozen=True)
class TelemetrySample:
    """One control tick as reported in :class:`Telemetry` (7 bytes on the wire).

    Parameters
    ----------
    reference_cdeg : int
        Reference in closed loop, setpoint in open loop, safe position when idle (centi-deg, i16).
    command_cdeg : int
        Servo command (centi-deg, i16); :data:`CDEG_NONE` while the servo output is off.
    adc : int
        Potentiometer reading (ADC counts, u16).
    flags : int
        :class:`SampleFlag` bits (u8); bits 0-1 are the mode.
    """

    reference_cdeg: int
    command_cdeg: int
    adc: int
    flags: int

    @property
    def reference_deg(self) -> float:
        """Reference (deg), NaN if absent."""
        return math.nan if self.reference_cdeg == CDEG_NONE else self.reference_cdeg / 100.0

    @property
    def command_deg(self) -> float:
        """Servo command (deg), NaN while the servo is off."""
        return math.nan if self.command_cdeg == CDEG_NONE else self.command_cdeg / 100.0

    @property
    def mode(self) -> int:
        """The device :class:`Mode` at this sample."""
        return self.flags & SampleFlag.MODE_MASK


SAMPLE_STRUCT = struct.Struct("<hhHB")
TELEMETRY_HEADER_STRUCT = struct.Struct("<IHB")


@dataclass(frozen=True)
class Telemetry(Message):
    """Device -> host, type 0x82: a batch of control-tick samples.

    Parameters
    ----------
    t0_us : int
        Device time (us, u32, wraps every 71.6 min) of ``samples[0]``.
    decimation : int
        Samples are ``decimation`` control ticks (``decimation * 1000`` us) apart (u16).
    samples : tuple of TelemetrySample
        1..32 samples, oldest first.
    """

    TYPE: ClassVar[int] = 0x82
    t0_us: int = 0
    decimation: int = 1
    samples: tuple[TelemetrySample, ...] = field(default_factory=tuple)

    def encode(self) -> bytes:
        name = type(self).__name__
        check_field(name, "t0_us", "I", self.t0_us)
        check_field(name, "decimation", "H", self.decimation)
        check_count(name, "samples", len(self.samples), TELEMETRY_MAX_SAMPLES)
        out = bytearray(
            TELEMETRY_HEADER_STRUCT.pack(self.t0_us, self.decimation, len(self.samples))
        )
        for s in self.samples:
            for f, code in zip(fields(s), SAMPLE_STRUCT.format[1:], strict=True):
                check_field("TelemetrySample", f.name, code, getattr(s, f.name))
            out += SAMPLE_STRUCT.pack(s.reference_cdeg, s.command_cdeg, s.adc, s.flags)
        return bytes(out)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        if len(payload) < TELEMETRY_HEADER_STRUCT.size:
            raise PayloadLengthError(
                f"Telemetry payload shorter than its 7-byte header: {len(payload)}"
            )
        t0_us, decimation, count = TELEMETRY_HEADER_STRUCT.unpack_from(payload)
        expected = TELEMETRY_HEADER_STRUCT.size + SAMPLE_STRUCT.size * count
        if not 1 <= count <= TELEMETRY_MAX_SAMPLES or len(payload) != expected:
            raise PayloadLengthError(
                f"Telemetry with {count} samples must be {expected} bytes "
                f"(1..{TELEMETRY_MAX_SAMPLES} samples), got {len(payload)}"
            )
        samples = tuple(
            TelemetrySample(
                *SAMPLE_STRUCT.unpack_from(
                    payload, TELEMETRY_HEADER_STRUCT.size + k * SAMPLE_STRUCT.size
                )
            )
            for k in range(count)
        )
        return cls(t0_us, decimation, samples)

    def times_us(self, tick_period_us: int = 1000) -> list[int]:
        """Device time (us, not wrapped) of each sample."""
        step = self.decimation * tick_period_us
        return [self.t0_us + k * step for k in range(len(self.samples))]


@dataclass(frozen=True)
class Status(FixedMessage):
    """Device -> host, type 0x83: state and link health (34 bytes).

    Sent in answer to CONFIGURE, SET_MODE, HEARTBEAT and ESTOP, and by itself when a fault
    latches. Error counters saturate at 65535.

    Parameters
    ----------
    device_time_us : int
        Device time (us, u32).
    echo : int
        Token of the last HEARTBEAT (u32).
    mode : int
        :class:`Mode` (u8).
    faults : int
        Latched :class:`Fault` bits (u8).
    flags : int
        :class:`StatusFlag` bits (u8).
    last_rx_seq : int
        Sequence number of the last valid host frame (u8).
    frames_ok : int
        Valid host frames received since reset (u32).
    frames_lost : int
        Host frames missing from the sequence since reset (u16).
    bad_crc : int
        Host frames dropped for a CRC mismatch (u16).
    bad_frame : int
        Host frames dropped as invalid COBS, truncated, oversized, or damaged by bytes lost on
        the receive path (u16).
    refused : int
        Host commands answered by ERROR (u16).
    tx_dropped : int
        Device frames dropped for lack of transmit buffer (u16).
    overruns : int
        Control ticks that started late (u16).
    rx_overflow : int
        Host bytes lost before the decoder: receive buffer full, UART overrun or framing error
        (u16).
    setpoint_deg : float
        The setpoint the device holds (deg, f32, as received, before the jaw clamp); NaN before
        any. The host confirms a setpoint by reading it back here.
    """

    TYPE: ClassVar[int] = 0x83
    _FORMAT: ClassVar[str] = "IIBBBBIHHHHHHHf"
    device_time_us: int = 0
    echo: int = 0
    mode: int = Mode.IDLE
    faults: int = 0
    flags: int = 0
    last_rx_seq: int = 0
    frames_ok: int = 0
    frames_lost: int = 0
    bad_crc: int = 0
    bad_frame: int = 0
    refused: int = 0
    tx_dropped: int = 0
    overruns: int = 0
    rx_overflow: int = 0
    setpoint_deg: float = math.nan


@dataclass(frozen=True)
class ErrorReport(FixedMessage):
    """Device -> host, type 0x84: a command was refused, or host frames were lost (5 bytes).

    Parameters
    ----------
    code : int
        :class:`ErrorCode` (u8).
    msg_type : int
        Type id of the refused frame (u8); 0 for FRAMES_LOST.
    seq : int
        Sequence number of the refused frame (u8); for FRAMES_LOST, the first missing one.
    detail : int
        Code-specific (u16): the device's protocol version for VERSION_MISMATCH, the received
        payload length for BAD_LENGTH, the field index for BAD_VALUE, the fault bits for
        FAULT_LATCHED, the number of frames missing for FRAMES_LOST.
    """

    TYPE: ClassVar[int] = 0x84
    _FORMAT: ClassVar[str] = "BBBH"
    code: int = 0
    msg_type: int = 0
    seq: int = 0
    detail: int = 0

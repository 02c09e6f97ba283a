"""Host side of the gripper's binary serial protocol (the firmware's ``gripper_protocol.h``).

A frame on the wire is ``COBS(seq | type | payload | crc16) + b"\\x00"``:

* ``seq`` (u8) counts frames per direction and wraps; a jump reveals lost frames.
* ``type`` (u8) is a message type id: host -> device below ``0x80``, device -> host above.
* ``payload`` is the message, packed little-endian field by field (at most 240 bytes).
* ``crc16`` is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0) over
  ``seq | type | payload``, little-endian.

The full specification, with every byte layout, unit, the handshake, watchdog and ESTOP
semantics, is ``firmware/PROTOCOL.md``.

Examples
--------
>>> frame = encode_frame(0, Hello())
>>> decoder = FrameDecoder()
>>> [received.message for received in decoder.feed(frame)]
[Hello(protocol_version=1)]
"""

from __future__ import annotations

import math
import struct
from dataclasses import astuple, dataclass, field, fields
from typing import ClassVar, Self

__all__ = [
    "CDEG_NONE",
    "MAX_ENCODED_FRAME",
    "MAX_PAYLOAD",
    "MESSAGE_TYPES",
    "PROFILE_CHUNK_MAX_SAMPLES",
    "PROTOCOL_VERSION",
    "TELEMETRY_MAX_SAMPLES",
    "AntiWindup",
    "CobsError",
    "Configure",
    "CrcError",
    "DecoderStats",
    "ErrorCode",
    "ErrorReport",
    "Estop",
    "Fault",
    "FieldValueError",
    "FrameDecoder",
    "FrameLengthError",
    "Heartbeat",
    "Hello",
    "Info",
    "Message",
    "Mode",
    "PayloadLengthError",
    "ProfileChunk",
    "ProtocolError",
    "ReceivedFrame",
    "SampleFlag",
    "SetMode",
    "Setpoint",
    "Status",
    "StatusFlag",
    "Telemetry",
    "TelemetrySample",
    "UnknownMessageTypeError",
    "cobs_decode",
    "cobs_encode",
    "crc16_ccitt_false",
    "decode_frame",
    "decode_payload",
    "encode_frame",
    "encode_raw_frame",
]

PROTOCOL_VERSION = 1
MAX_PAYLOAD = 240  # bytes of payload in one frame
MAX_RAW_FRAME = MAX_PAYLOAD + 4  # seq + type + payload + crc16
MAX_ENCODED_FRAME = MAX_RAW_FRAME + 2  # COBS-encoded, without the delimiter
TELEMETRY_MAX_SAMPLES = 32
PROFILE_CHUNK_MAX_SAMPLES = 100
CDEG_NONE = -32768  # "no value" in a centi-degree field (the servo is off)
_FLT_MAX = 3.4028234663852886e38


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------


class ProtocolError(Exception):
    """Base class of every error raised while encoding or decoding frames."""


class CobsError(ProtocolError):
    """The bytes between two delimiters are not valid COBS."""


class CrcError(ProtocolError):
    """The frame's CRC-16 does not match its contents."""

    def __init__(self, received: int, computed: int) -> None:
        super().__init__(
            f"CRC mismatch: frame carries 0x{received:04x}, contents give 0x{computed:04x}"
        )
        self.received = received
        self.computed = computed


class FrameLengthError(ProtocolError):
    """The frame is shorter than seq + type + CRC (truncated) or longer than allowed."""


class UnknownMessageTypeError(ProtocolError):
    """The frame's type id names no message of this protocol version."""


class PayloadLengthError(ProtocolError):
    """The payload length does not fit the message type."""


class FieldValueError(ProtocolError, ValueError):
    """A message field cannot be represented in its wire type."""


# --------------------------------------------------------------------------------------------
# Enumerations (plain int constants, as on the wire)
# --------------------------------------------------------------------------------------------


class Mode:
    """Device modes (``SetMode.mode``, ``Status.mode``)."""

    IDLE = 0
    OPEN_LOOP = 1
    CLOSED_LOOP = 2


class AntiWindup:
    """Anti-windup modes (``Configure.anti_windup``), as in ``gripper_env.pid``."""

    NONE = 0
    CLAMPING = 1
    BACK_CALCULATION = 2


class Fault:
    """Latched fault bits (``Status.faults``)."""

    WATCHDOG = 0x01
    ESTOP = 0x02
    NUMERIC = 0x04
    SENSOR = 0x08


class StatusFlag:
    """Bits of ``Status.flags``."""

    SESSION = 0x01
    CONFIGURED = 0x02
    SERVO_ON = 0x04


class SampleFlag:
    """Bits of ``TelemetrySample.flags``; bits 0-1 hold the mode."""

    MODE_MASK = 0x03
    SATURATED = 0x04
    OVERRUN = 0x08
    FAULT = 0x10
    SERVO_ON = 0x20
    CLAMPED = 0x40


class ErrorCode:
    """``ErrorReport.code`` values."""

    NO_SESSION = 1
    VERSION_MISMATCH = 2
    BAD_LENGTH = 3
    BAD_VALUE = 4
    UNKNOWN_TYPE = 5
    FAULT_LATCHED = 6
    NOT_CONFIGURED = 7
    UNSUPPORTED = 8


# --------------------------------------------------------------------------------------------
# CRC and COBS
# --------------------------------------------------------------------------------------------


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data``.

    Parameters
    ----------
    data : bytes
        The bytes to check.
    crc : int
        Initial value, 0xFFFF for a fresh CRC; pass a previous result to continue it.

    Returns
    -------
    int
        The CRC, 0..0xFFFF. ``crc16_ccitt_false(b"123456789") == 0x29B1``.
    """
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[(crc >> 8) ^ byte]
    return crc


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing: return ``data`` with no zero byte, delimiter not added.

    A final block of 254 non-zero bytes gets no trailing ``0x01`` code (canonical COBS, as in the
    firmware), so the output is at most ``len(data) + len(data) // 254 + 1`` bytes.
    """
    out = bytearray()
    block = bytearray()
    for index, byte in enumerate(data):
        if byte:
            block.append(byte)
            if len(block) == 254:
                out.append(0xFF)
                out += block
                block.clear()
                if index == len(data) - 1:
                    return bytes(out)
        else:
            out.append(len(block) + 1)
            out += block
            block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode` (input without the delimiter).

    Raises
    ------
    CobsError
        If ``data`` contains a zero byte or a block runs past its end.
    """
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise CobsError(f"zero byte at offset {i} inside a COBS block")
        end = i + code
        if end > n:
            raise CobsError(f"COBS block at offset {i} needs {code - 1} bytes, {n - i - 1} left")
        block = data[i + 1 : end]
        if 0 in block:
            raise CobsError(f"zero byte at offset {i + 1 + block.index(0)} inside a COBS block")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


# --------------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------------

_INT_RANGES = {
    "B": (0, 0xFF),
    "b": (-0x80, 0x7F),
    "H": (0, 0xFFFF),
    "h": (-0x8000, 0x7FFF),
    "I": (0, 0xFFFFFFFF),
}


def _check_field(message: str, name: str, code: str, value: object) -> None:
    """Raise :class:`FieldValueError` unless ``value`` fits struct format ``code``."""
    if code == "f":
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise FieldValueError(f"{message}.{name} must be a number, got {value!r}")
        if math.isfinite(value) and abs(value) > _FLT_MAX:
            raise FieldValueError(f"{message}.{name}={value!r} overflows float32")
        return
    lo, hi = _INT_RANGES[code]
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise FieldValueError(f"{message}.{name} must be an integer in [{lo}, {hi}], got {value!r}")


class Message:
    """Base class of all messages: ``encode()`` gives the payload, ``decode()`` parses one."""

    TYPE: ClassVar[int]

    def encode(self) -> bytes:
        """Return the payload bytes of this message."""
        raise NotImplementedError

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        """Parse a payload of this message type.

        Raises
        ------
        PayloadLengthError
            If the payload length does not fit the type.
        """
        raise NotImplementedError


class _FixedMessage(Message):
    """A message whose payload is its dataclass fields packed with ``_FORMAT`` (one char each)."""

    _FORMAT: ClassVar[str] = ""
    _STRUCT: ClassVar[struct.Struct]

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls._STRUCT = struct.Struct("<" + cls._FORMAT)

    def encode(self) -> bytes:
        values = astuple(self)
        for f, code, value in zip(fields(self), self._FORMAT, values, strict=True):
            _check_field(type(self).__name__, f.name, code, value)
        return self._STRUCT.pack(*values)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        if len(payload) != cls._STRUCT.size:
            raise PayloadLengthError(
                f"{cls.__name__} payload must be {cls._STRUCT.size} bytes, got {len(payload)}"
            )
        return cls(*cls._STRUCT.unpack(payload))


@dataclass(frozen=True)
class Hello(_FixedMessage):
    """Host -> device, type 0x01: open a session. Answered by :class:`Info` or an ERROR.

    Parameters
    ----------
    protocol_version : int
        The protocol version the host speaks (u16).
    """

    TYPE: ClassVar[int] = 0x01
    _FORMAT: ClassVar[str] = "H"
    protocol_version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class Configure(_FixedMessage):
    """Host -> device, type 0x02: controller, calibration and telemetry settings (50 bytes).

    Parameters
    ----------
    p, i, d, n : float
        PID gains (float32): proportional (deg/deg), integral (1/s), derivative (s) and the
        derivative filter coefficient (1/s, ``0 < n * 1e-3 < 2``).
    u_min, u_max : float
        PID output limits (deg, float32, may be infinite); the device intersects them with the
        jaw range.
    kb : float
        Back-calculation gain (1/s).
    jaw_min, jaw_max : float
        Jaw range (deg) every servo command is clamped into; inside [0, 180]. ``jaw_max`` is the
        safe (open) position.
    adc_at_lo, adc_at_hi : int
        ADC counts (u16, 4..1019) read with the jaw at 21 deg and at 92 deg.
    servo_us_at_0, servo_us_at_180 : int
        Servo pulse widths (us, u16, 400..2600) for 0 and 180 deg.
    decimation : int
        One telemetry sample every ``decimation`` control ticks (u16, 0 = telemetry off).
    anti_windup : int
        :class:`AntiWindup` value (u8).
    sign : int
        +1 for ``e = r - y``, -1 for ``e = y - r`` (i8).
    d_on_meas : int
        1 to differentiate ``-sign * y`` instead of the error (u8).
    telemetry_batch : int
        Samples per TELEMETRY frame (u8, 1..32).
    """

    TYPE: ClassVar[int] = 0x02
    _FORMAT: ClassVar[str] = "fffffffffHHHHHBbBB"
    p: float = 0.0
    i: float = 0.0
    d: float = 0.0
    n: float = 100.0
    u_min: float = 21.0
    u_max: float = 92.0
    kb: float = 1.0
    jaw_min: float = 21.0
    jaw_max: float = 92.0
    adc_at_lo: int = 119
    adc_at_hi: int = 523
    servo_us_at_0: int = 544
    servo_us_at_180: int = 2400
    decimation: int = 1
    anti_windup: int = AntiWindup.CLAMPING
    sign: int = 1
    d_on_meas: int = 0
    telemetry_batch: int = 10


@dataclass(frozen=True)
class SetMode(_FixedMessage):
    """Host -> device, type 0x03: switch to a :class:`Mode` (u8). Answered by STATUS or ERROR."""

    TYPE: ClassVar[int] = 0x03
    _FORMAT: ClassVar[str] = "B"
    mode: int = Mode.IDLE


@dataclass(frozen=True)
class Setpoint(_FixedMessage):
    """Host -> device, type 0x04: the desired jaw angle (deg, float32); no reply unless refused.

    In open loop it is the servo command, in closed loop the PID reference; the device clamps it
    into the jaw range and refuses NaN and infinities.
    """

    TYPE: ClassVar[int] = 0x04
    _FORMAT: ClassVar[str] = "f"
    angle_deg: float = 92.0


@dataclass(frozen=True)
class ProfileChunk(Message):
    """Host -> device, type 0x05: part of a reference profile (reserved for profile playback).

    Firmware protocol version 1 decodes it and answers ERROR ``UNSUPPORTED``.

    Parameters
    ----------
    start_index : int
        Index of ``samples_cdeg[0]`` in the whole profile (u16).
    total_length : int
        Number of samples in the whole profile (u16).
    samples_cdeg : tuple of int
        1..100 reference samples in centi-degrees (i16), one per control tick.
    """

    TYPE: ClassVar[int] = 0x05
    start_index: int = 0
    total_length: int = 0
    samples_cdeg: tuple[int, ...] = ()

    def encode(self) -> bytes:
        name = type(self).__name__
        _check_field(name, "start_index", "H", self.start_index)
        _check_field(name, "total_length", "H", self.total_length)
        if not 1 <= len(self.samples_cdeg) <= PROFILE_CHUNK_MAX_SAMPLES:
            raise FieldValueError(
                f"{name}.samples_cdeg must hold 1..{PROFILE_CHUNK_MAX_SAMPLES} samples, "
                f"got {len(self.samples_cdeg)}"
            )
        for value in self.samples_cdeg:
            _check_field(name, "samples_cdeg", "h", value)
        count = len(self.samples_cdeg)
        return struct.pack(f"<HH{count}h", self.start_index, self.total_length, *self.samples_cdeg)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        n = len(payload)
        if n < 6 or (n - 4) % 2 or (n - 4) // 2 > PROFILE_CHUNK_MAX_SAMPLES:
            raise PayloadLengthError(
                "ProfileChunk payload must be 4 + 2*k bytes with k in "
                f"1..{PROFILE_CHUNK_MAX_SAMPLES}, got {n}"
            )
        start, total = struct.unpack_from("<HH", payload)
        samples = struct.unpack_from(f"<{(n - 4) // 2}h", payload, 4)
        return cls(start, total, tuple(samples))


@dataclass(frozen=True)
class Heartbeat(_FixedMessage):
    """Host -> device, type 0x06: feed the watchdog; answered by STATUS echoing ``token`` (u32)."""

    TYPE: ClassVar[int] = 0x06
    _FORMAT: ClassVar[str] = "I"
    token: int = 0


@dataclass(frozen=True)
class Estop(_FixedMessage):
    """Host -> device, type 0x07: emergency stop (empty payload), honoured even before HELLO."""

    TYPE: ClassVar[int] = 0x07
    _FORMAT: ClassVar[str] = ""


@dataclass(frozen=True)
class Info(_FixedMessage):
    """Device -> host, type 0x81: answer to a matching HELLO (13 bytes).

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
    """

    TYPE: ClassVar[int] = 0x81
    _FORMAT: ClassVar[str] = "HBBBIHBB"
    protocol_version: int = PROTOCOL_VERSION
    fw_major: int = 0
    fw_minor: int = 0
    fw_patch: int = 0
    device_id: int = 0xFFFFFFFF
    tick_period_us: int = 1000
    max_batch: int = TELEMETRY_MAX_SAMPLES
    max_payload: int = MAX_PAYLOAD


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


_SAMPLE = struct.Struct("<hhHB")
_TELEMETRY_HEADER = struct.Struct("<IHB")


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
        _check_field(name, "t0_us", "I", self.t0_us)
        _check_field(name, "decimation", "H", self.decimation)
        if not 1 <= len(self.samples) <= TELEMETRY_MAX_SAMPLES:
            raise FieldValueError(
                f"{name}.samples must hold 1..{TELEMETRY_MAX_SAMPLES} samples, "
                f"got {len(self.samples)}"
            )
        out = bytearray(_TELEMETRY_HEADER.pack(self.t0_us, self.decimation, len(self.samples)))
        for s in self.samples:
            for f, code in zip(fields(s), _SAMPLE.format[1:], strict=True):
                _check_field("TelemetrySample", f.name, code, getattr(s, f.name))
            out += _SAMPLE.pack(s.reference_cdeg, s.command_cdeg, s.adc, s.flags)
        return bytes(out)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        if len(payload) < _TELEMETRY_HEADER.size:
            raise PayloadLengthError(
                f"Telemetry payload shorter than its 7-byte header: {len(payload)}"
            )
        t0_us, decimation, count = _TELEMETRY_HEADER.unpack_from(payload)
        expected = _TELEMETRY_HEADER.size + _SAMPLE.size * count
        if not 1 <= count <= TELEMETRY_MAX_SAMPLES or len(payload) != expected:
            raise PayloadLengthError(
                f"Telemetry with {count} samples must be {expected} bytes "
                f"(1..{TELEMETRY_MAX_SAMPLES} samples), got {len(payload)}"
            )
        samples = tuple(
            TelemetrySample(
                *_SAMPLE.unpack_from(payload, _TELEMETRY_HEADER.size + k * _SAMPLE.size)
            )
            for k in range(count)
        )
        return cls(t0_us, decimation, samples)

    def times_us(self, tick_period_us: int = 1000) -> list[int]:
        """Device time (us, not wrapped) of each sample."""
        step = self.decimation * tick_period_us
        return [self.t0_us + k * step for k in range(len(self.samples))]


@dataclass(frozen=True)
class Status(_FixedMessage):
    """Device -> host, type 0x83: state and link health (28 bytes).

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
        Host frames dropped as invalid COBS, truncated or oversized (u16).
    refused : int
        Host commands answered by ERROR (u16).
    tx_dropped : int
        Device frames dropped for lack of transmit buffer (u16).
    overruns : int
        Control ticks that started late (u16).
    """

    TYPE: ClassVar[int] = 0x83
    _FORMAT: ClassVar[str] = "IIBBBBIHHHHHH"
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


@dataclass(frozen=True)
class ErrorReport(_FixedMessage):
    """Device -> host, type 0x84: a command was refused (5 bytes).

    Parameters
    ----------
    code : int
        :class:`ErrorCode` (u8).
    msg_type : int
        Type id of the refused frame (u8).
    seq : int
        Sequence number of the refused frame (u8).
    detail : int
        Code-specific (u16): the device's protocol version for VERSION_MISMATCH, the received
        payload length for BAD_LENGTH, the field index for BAD_VALUE, the fault bits for
        FAULT_LATCHED.
    """

    TYPE: ClassVar[int] = 0x84
    _FORMAT: ClassVar[str] = "BBBH"
    code: int = 0
    msg_type: int = 0
    seq: int = 0
    detail: int = 0


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls
    for cls in (
        Hello,
        Configure,
        SetMode,
        Setpoint,
        ProfileChunk,
        Heartbeat,
        Estop,
        Info,
        Telemetry,
        Status,
        ErrorReport,
    )
}


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------


def encode_raw_frame(seq: int, type_id: int, payload: bytes) -> bytes:
    """Frame an arbitrary payload: ``COBS(seq | type | payload | crc16 LE) + b"\\x00"``.

    Raises
    ------
    FieldValueError
        If ``seq`` or ``type_id`` is not a u8.
    FrameLengthError
        If the payload exceeds :data:`MAX_PAYLOAD` bytes.
    """
    _check_field("frame", "seq", "B", seq)
    _check_field("frame", "type", "B", type_id)
    if len(payload) > MAX_PAYLOAD:
        raise FrameLengthError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((seq, type_id)) + payload
    return cobs_encode(body + crc16_ccitt_false(body).to_bytes(2, "little")) + b"\x00"


def encode_frame(seq: int, msg: Message) -> bytes:
    """Encode ``msg`` as a complete wire frame with sequence number ``seq`` (0..255)."""
    return encode_raw_frame(seq, msg.TYPE, msg.encode())


def decode_payload(type_id: int, payload: bytes) -> Message:
    """Parse a payload of message type ``type_id``.

    Raises
    ------
    UnknownMessageTypeError, PayloadLengthError
    """
    cls = MESSAGE_TYPES.get(type_id)
    if cls is None:
        raise UnknownMessageTypeError(f"unknown message type 0x{type_id:02x}")
    return cls.decode(payload)


def _unframe(encoded: bytes) -> tuple[int, int, bytes]:
    """COBS-decode and CRC-check one frame (no delimiter); return ``(seq, type, payload)``."""
    if len(encoded) > MAX_ENCODED_FRAME:
        raise FrameLengthError(f"frame of {len(encoded)} encoded bytes exceeds {MAX_ENCODED_FRAME}")
    raw = cobs_decode(encoded)
    if len(raw) < 4:
        raise FrameLengthError(f"truncated frame: {len(raw)} bytes, need at least 4")
    if len(raw) > MAX_RAW_FRAME:
        raise FrameLengthError(f"frame of {len(raw)} bytes exceeds {MAX_RAW_FRAME}")
    received = int.from_bytes(raw[-2:], "little")
    computed = crc16_ccitt_false(raw[:-2])
    if received != computed:
        raise CrcError(received, computed)
    return raw[0], raw[1], raw[2:-2]


def decode_frame(wire: bytes) -> tuple[int, Message]:
    """Decode one complete frame, with or without its trailing ``0x00``.

    Returns
    -------
    seq : int
        The frame's sequence number.
    message : Message
        The decoded message.

    Raises
    ------
    ProtocolError
        :class:`CobsError`, :class:`FrameLengthError`, :class:`CrcError`,
        :class:`UnknownMessageTypeError` or :class:`PayloadLengthError`, naming the problem.
    """
    if wire.endswith(b"\x00"):
        wire = wire[:-1]
    seq, type_id, payload = _unframe(wire)
    return seq, decode_payload(type_id, payload)


@dataclass(frozen=True)
class ReceivedFrame:
    """A decoded frame from :meth:`FrameDecoder.feed`.

    Parameters
    ----------
    seq : int
        Sequence number.
    message : Message
        The decoded message.
    gap : int
        Frames missing between the previous valid frame and this one (0 normally).
    """

    seq: int
    message: Message
    gap: int = 0


@dataclass
class DecoderStats:
    """Counters of a :class:`FrameDecoder`.

    Attributes
    ----------
    frames : int
        Frames that passed the CRC (including those with an unknown type or bad payload).
    messages : int
        Frames decoded into messages.
    discarded_bytes : int
        Bytes thrown away: rejected frames and bytes skipped while resynchronising.
    bad_cobs, bad_crc, truncated, oversized : int
        Frames rejected for each reason.
    bad_message : int
        CRC-valid frames with an unknown type or a payload that does not fit it.
    lost : int
        Frames missing from the sequence (sum of the gaps).
    gaps : int
        Number of places where frames were missing.
    """

    frames: int = 0
    messages: int = 0
    discarded_bytes: int = 0
    bad_cobs: int = 0
    bad_crc: int = 0
    truncated: int = 0
    oversized: int = 0
    bad_message: int = 0
    lost: int = 0
    gaps: int = 0

    @property
    def rejected(self) -> int:
        """Frames rejected for any reason."""
        return self.bad_cobs + self.bad_crc + self.truncated + self.oversized + self.bad_message


class FrameDecoder:
    """Turn an arbitrary byte stream into messages; never raises on bad input.

    Feed it whatever the serial port returns; it splits on ``0x00``, drops frames that are not
    valid COBS, are too short or too long, fail the CRC or do not parse, counts each reason in
    :attr:`stats`, keeps the last reason in :attr:`last_error`, and resynchronises at the next
    delimiter.

    Parameters
    ----------
    synced : bool
        ``True`` (default) treats the first bytes as the start of a frame. ``False`` discards
        everything up to the first ``0x00``: use it when joining a stream mid-frame.
    max_encoded : int
        Longest accepted frame in bytes, without the delimiter.
    """

    def __init__(self, *, synced: bool = True, max_encoded: int = MAX_ENCODED_FRAME) -> None:
        self.stats = DecoderStats()
        self.last_error: ProtocolError | None = None
        self._max = max_encoded
        self._buffer = bytearray()
        self._overflow = False
        self._synced = synced
        self._last_seq: int | None = None

    def reset_sequence(self) -> None:
        """Forget the last sequence number (after a device reset): no gap is counted next."""
        self._last_seq = None

    def feed(self, data: bytes) -> list[ReceivedFrame]:
        """Consume ``data`` and return the frames it completed, in order."""
        out: list[ReceivedFrame] = []
        start = 0
        while True:
            end = data.find(0, start)
            chunk = data[start:] if end < 0 else data[start:end]
            if not self._synced:
                self.stats.discarded_bytes += len(chunk)
            elif not self._overflow:
                room = self._max - len(self._buffer)
                self._buffer += chunk[:room]
                if len(chunk) > room:
                    self._overflow = True
                    self.stats.discarded_bytes += len(chunk) - room
            else:
                self.stats.discarded_bytes += len(chunk)
            if end < 0:
                return out
            self._synced = True
            received = self._finish()
            if received is not None:
                out.append(received)
            start = end + 1

    def _reject(self, counter: str, error: ProtocolError, n: int) -> None:
        setattr(self.stats, counter, getattr(self.stats, counter) + 1)
        self.stats.discarded_bytes += n
        self.last_error = error

    def _finish(self) -> ReceivedFrame | None:
        encoded = bytes(self._buffer)
        overflow = self._overflow
        self._buffer.clear()
        self._overflow = False
        if overflow:
            self._reject(
                "oversized", FrameLengthError(f"frame longer than {self._max} bytes"), len(encoded)
            )
            return None
        if not encoded:
            return None  # back-to-back delimiters are idle fill
        try:
            seq, type_id, payload = _unframe(encoded)
        except CobsError as exc:
            self._reject("bad_cobs", exc, len(encoded))
            return None
        except CrcError as exc:
            self._reject("bad_crc", exc, len(encoded))
            return None
        except FrameLengthError as exc:
            counter = "truncated" if "truncated" in str(exc) else "oversized"
            self._reject(counter, exc, len(encoded))
            return None
        self.stats.frames += 1
        gap = 0 if self._last_seq is None else (seq - self._last_seq - 1) & 0xFF
        if gap:
            self.stats.lost += gap
            self.stats.gaps += 1
        self._last_seq = seq
        try:
            message = decode_payload(type_id, payload)
        except ProtocolError as exc:
            self.stats.bad_message += 1
            self.last_error = exc
            return None
        self.stats.messages += 1
        return ReceivedFrame(seq, message, gap)

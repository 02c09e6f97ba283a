"""The message base classes and the host -> device messages (commands).

A message's ``encode()`` gives its payload, packed little-endian field by field;
``decode(payload)`` parses one. The device -> host messages are in
:mod:`~gripper_env.hardware.protocol.reports`.
"""

from __future__ import annotations

import struct
from dataclasses import astuple, dataclass, fields
from typing import Any, ClassVar, Self

from gripper_env.hardware.protocol.constants import (
    PROFILE_CHUNK_MAX_SAMPLES,
    PROTOCOL_VERSION,
    AntiWindup,
    Mode,
)
from gripper_env.hardware.protocol.errors import PayloadLengthError
from gripper_env.hardware.protocol.wire import check_count, check_field

__all__ = [
    "Configure",
    "Estop",
    "FixedMessage",
    "Heartbeat",
    "Hello",
    "Message",
    "ProfileChunk",
    "SetMode",
    "Setpoint",
]


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


class FixedMessage(Message):
    """A message whose payload is its dataclass fields packed with ``_FORMAT`` (one char each)."""

    _FORMAT: ClassVar[str] = ""
    _STRUCT: ClassVar[struct.Struct]
    __dataclass_fields__: ClassVar[dict[str, Any]]  # every subclass is a dataclass

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls._STRUCT = struct.Struct("<" + cls._FORMAT)

    def encode(self) -> bytes:
        values = astuple(self)
        for f, code, value in zip(fields(self), self._FORMAT, values, strict=True):
            check_field(type(self).__name__, f.name, code, value)
        return self._STRUCT.pack(*values)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        if len(payload) != cls._STRUCT.size:
            raise PayloadLengthError(
                f"{cls.__name__} payload must be {cls._STRUCT.size} bytes, got {len(payload)}"
            )
        return cls(*cls._STRUCT.unpack(payload))


@dataclass(frozen=True)
class Hello(FixedMessage):
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
class Configure(FixedMessage):
    """Host -> device, type 0x02: controller, calibration and telemetry settings (69 bytes).

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
        Jaw range (deg) every servo command is clamped into; inside the image's hard jaw range
        (:attr:`Info.hard_jaw_min_deg` .. ``hard_jaw_max_deg``, 21..92 by default). ``jaw_max``
        is the safe (open) position.
    adc_at_lo, adc_at_hi : int
        ADC counts (u16, 4..1019) read with the jaw at 21 deg and at 92 deg.
    servo_us_at_0, servo_us_at_180 : int
        Servo pulse widths (us, u16, 400..2600) for 0 and 180 deg; the pulses they give
        ``jaw_min`` and ``jaw_max`` must lie in the image's hard pulse window
        (:attr:`Info.hard_pulse_min_us` .. ``hard_pulse_max_us``).
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
    grasp : int
        1 for the PID's grasp mode (:class:`gripper_env.model.pid.GraspOptions`), 0 for none
        (u8); with 0 the five fields below are not checked.
    grasp_squeeze_deg, grasp_push_deg, grasp_short_deg, grasp_still_deg : float
        The grasp mode's squeeze past the contact (``> 0``), command past the jaw that reads as
        blocked (``> grasp_squeeze_deg``), jaw short of the reference that reads as blocked
        (``> 0``) and motion that still counts as still (``> 0``), deg (float32).
    grasp_dwell_ticks : int
        Control ticks (1 ms) the jaw must stay blocked before the mode holds (u16, ``>= 1``).
    """

    TYPE: ClassVar[int] = 0x02
    _FORMAT: ClassVar[str] = "fffffffffHHHHHBbBBBffffH"
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
    grasp: int = 1
    grasp_squeeze_deg: float = 1.0
    grasp_push_deg: float = 5.0
    grasp_short_deg: float = 0.5
    grasp_still_deg: float = 1.0
    grasp_dwell_ticks: int = 100


@dataclass(frozen=True)
class SetMode(FixedMessage):
    """Host -> device, type 0x03: switch to a :class:`Mode` (u8). Answered by STATUS or ERROR."""

    TYPE: ClassVar[int] = 0x03
    _FORMAT: ClassVar[str] = "B"
    mode: int = Mode.IDLE


@dataclass(frozen=True)
class Setpoint(FixedMessage):
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
        check_field(name, "start_index", "H", self.start_index)
        check_field(name, "total_length", "H", self.total_length)
        check_count(name, "samples_cdeg", len(self.samples_cdeg), PROFILE_CHUNK_MAX_SAMPLES)
        for value in self.samples_cdeg:
            check_field(name, "samples_cdeg", "h", value)
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
class Heartbeat(FixedMessage):
    """Host -> device, type 0x06: feed the watchdog; answered by STATUS echoing ``token`` (u32)."""

    TYPE: ClassVar[int] = 0x06
    _FORMAT: ClassVar[str] = "I"
    token: int = 0


@dataclass(frozen=True)
class Estop(FixedMessage):
    """Host -> device, type 0x07: emergency stop (empty payload), honoured even before HELLO."""

    TYPE: ClassVar[int] = 0x07
    _FORMAT: ClassVar[str] = ""

"""The protocol's constants and enumerations (plain int constants, as on the wire).

The values are those of ``firmware/protocol.toml`` (checked by ``python -m
gripper_env.hardware.layouts --check``).
"""

from __future__ import annotations

__all__ = [
    "CDEG_NONE",
    "FLT_MAX",
    "MAX_ENCODED_FRAME",
    "MAX_PAYLOAD",
    "MAX_RAW_FRAME",
    "PROFILE_CHUNK_MAX_SAMPLES",
    "PROTOCOL_VERSION",
    "TELEMETRY_MAX_SAMPLES",
    "AntiWindup",
    "ErrorCode",
    "Fault",
    "Mode",
    "SampleFlag",
    "StatusFlag",
]

PROTOCOL_VERSION = 3
MAX_PAYLOAD = 240  # bytes of payload in one frame
MAX_RAW_FRAME = MAX_PAYLOAD + 4  # seq + type + payload + crc16
MAX_ENCODED_FRAME = MAX_RAW_FRAME + 2  # COBS-encoded, without the delimiter
TELEMETRY_MAX_SAMPLES = 32
PROFILE_CHUNK_MAX_SAMPLES = 100
CDEG_NONE = -32768  # "no value" in a centi-degree field (the servo is off)
FLT_MAX = 3.4028234663852886e38  # largest float32


class Mode:
    """Device modes (``SetMode.mode``, ``Status.mode``)."""

    IDLE = 0
    OPEN_LOOP = 1
    CLOSED_LOOP = 2


class AntiWindup:
    """Anti-windup modes (``Configure.anti_windup``), as in ``gripper_env.model.pid``."""

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
    GRASP = 0x80


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
    FRAMES_LOST = 9  # a report: host frames missing from the sequence, ``seq`` the first

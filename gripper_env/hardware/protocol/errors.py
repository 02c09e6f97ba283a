"""Errors raised while encoding or decoding frames of the serial protocol."""

from __future__ import annotations

__all__ = [
    "CobsError",
    "CrcError",
    "FieldValueError",
    "FrameLengthError",
    "PayloadLengthError",
    "ProtocolError",
    "UnknownMessageTypeError",
]


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

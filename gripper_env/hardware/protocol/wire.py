"""Wire-level helpers: CRC-16/CCITT-FALSE, COBS, and the range check of a packed field.

The twin of the firmware's ``gripper_wire.h``.
"""

from __future__ import annotations

import math

from gripper_env.hardware.protocol.constants import FLT_MAX
from gripper_env.hardware.protocol.errors import CobsError, FieldValueError

__all__ = ["check_count", "check_field", "cobs_decode", "cobs_encode", "crc16_ccitt_false"]


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


_INT_RANGES = {
    "B": (0, 0xFF),
    "b": (-0x80, 0x7F),
    "H": (0, 0xFFFF),
    "h": (-0x8000, 0x7FFF),
    "I": (0, 0xFFFFFFFF),
}


def check_field(message: str, name: str, code: str, value: object) -> None:
    """Raise :class:`FieldValueError` unless ``value`` fits struct format ``code``."""
    if code == "f":
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise FieldValueError(f"{message}.{name} must be a number, got {value!r}")
        if math.isfinite(value) and abs(value) > FLT_MAX:
            raise FieldValueError(f"{message}.{name}={value!r} overflows float32")
        return
    lo, hi = _INT_RANGES[code]
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise FieldValueError(f"{message}.{name} must be an integer in [{lo}, {hi}], got {value!r}")


def check_count(message: str, name: str, n: int, most: int) -> None:
    """Raise :class:`FieldValueError` unless an array field holds 1..``most`` samples."""
    if not 1 <= n <= most:
        raise FieldValueError(f"{message}.{name} must hold 1..{most} samples, got {n}")

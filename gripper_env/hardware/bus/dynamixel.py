"""Dynamixel Protocol 2.0 packets: framing, CRC-16, byte stuffing and an incremental parser.

A packet (ROBOTIS e-manual, "Protocol 2.0")::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM... | CRC_L CRC_H

``LEN`` counts the instruction, the parameters and the CRC, after byte stuffing. A status
packet is one whose instruction is :data:`INST_STATUS` (0x55) and whose first parameter is the
error byte: bit 7 the hardware alert (see the servo's Hardware Error Status), bits 0-6 an error
number (:data:`ERR_RESULT_FAIL` ... :data:`ERR_ACCESS`).

The CRC is CRC-16 with polynomial 0x8005, initial value 0, unreflected, over every byte from
the header to the last parameter (stuffed); :func:`crc16` uses the same table as the
e-manual's ``update_crc`` and the SDK's ``updateCRC``.

Byte stuffing keeps the header out of the payload: in the instruction and parameters, each
``FF FF FD`` becomes ``FF FF FD FD`` (:func:`stuff`); the receiver removes the extra ``FD``
after checking the CRC (:func:`unstuff`).
"""

from __future__ import annotations

from dataclasses import dataclass

from gripper_env.hardware.bus.framing import FrameParser

__all__ = [
    "BROADCAST_ID",
    "ERRBIT_ALERT",
    "ERROR_TEXT",
    "ERR_ACCESS",
    "ERR_CRC",
    "ERR_DATA_LENGTH",
    "ERR_DATA_LIMIT",
    "ERR_DATA_RANGE",
    "ERR_INSTRUCTION",
    "ERR_RESULT_FAIL",
    "HEADER",
    "INST_ACTION",
    "INST_BULK_READ",
    "INST_BULK_WRITE",
    "INST_CLEAR",
    "INST_FACTORY_RESET",
    "INST_PING",
    "INST_READ",
    "INST_REBOOT",
    "INST_REG_WRITE",
    "INST_STATUS",
    "INST_SYNC_READ",
    "INST_SYNC_WRITE",
    "INST_WRITE",
    "MAX_ID",
    "Packet",
    "Parser",
    "crc16",
    "decode_packet",
    "encode_instruction",
    "encode_packet",
    "encode_status",
    "stuff",
    "unstuff",
]

HEADER = b"\xff\xff\xfd\x00"  # three header bytes and the reserved byte
BROADCAST_ID = 0xFE
MAX_ID = 0xFC  # 253 (0xFD) and 255 are never IDs: they would look like a header

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93

ERRBIT_ALERT = 0x80  # the device has a hardware error (see its Hardware Error Status)
ERR_RESULT_FAIL = 1  # failed to process the instruction
ERR_INSTRUCTION = 2  # undefined instruction, or ACTION without REG_WRITE
ERR_CRC = 3  # the packet's CRC does not match
ERR_DATA_RANGE = 4  # value outside the register's range
ERR_DATA_LENGTH = 5  # data shorter than the register
ERR_DATA_LIMIT = 6  # value outside the limit another register sets
ERR_ACCESS = 7  # read-only or undefined address, or EEPROM while torque is on

#: The e-manual's name of each error number.
ERROR_TEXT = {
    ERR_RESULT_FAIL: "result fail",
    ERR_INSTRUCTION: "instruction error",
    ERR_CRC: "CRC error",
    ERR_DATA_RANGE: "data range error",
    ERR_DATA_LENGTH: "data length error",
    ERR_DATA_LIMIT: "data limit error",
    ERR_ACCESS: "access error",
}

_MAX_LENGTH = 1024  # the SDK's RXPACKET_MAX_LEN: longer LEN fields are garbage


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = (crc << 1) ^ 0x8005 if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 (polynomial 0x8005, unreflected) of ``data``, continuing from ``crc``."""
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


def stuff(body: bytes) -> bytes:
    """``body`` (instruction and parameters) with an ``FD`` added after each ``FF FF FD``."""
    out = bytearray()
    for k, byte in enumerate(body):
        out.append(byte)
        if byte == 0xFD and k >= 2 and body[k - 2] == 0xFF and body[k - 1] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Undo :func:`stuff`: drop the ``FD`` that follows each ``FF FF FD``."""
    out = bytearray()
    k = 0
    while k < len(body):
        byte = body[k]
        out.append(byte)
        k += 1
        stuffed = len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF and byte == 0xFD
        if stuffed and k < len(body) and body[k] == 0xFD:
            k += 1
    return bytes(out)


@dataclass(frozen=True)
class Packet:
    """A decoded packet (unstuffed).

    Attributes
    ----------
    id : int
        Packet ID.
    instruction : int
        ``INST_*`` (:data:`INST_STATUS` for a status packet).
    params : bytes
        The parameters; for a status packet the error byte comes first.
    """

    id: int
    instruction: int
    params: bytes = b""

    @property
    def is_status(self) -> bool:
        return self.instruction == INST_STATUS

    @property
    def error(self) -> int:
        """The error byte of a status packet."""
        if not self.is_status or not self.params:
            raise ValueError("not a status packet")
        return self.params[0]

    @property
    def data(self) -> bytes:
        """A status packet's parameters after the error byte."""
        return self.params[1:] if self.is_status else self.params

    def encode(self) -> bytes:
        return encode_packet(self.id, self.instruction, self.params)


def encode_packet(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """The bytes on the wire: header, ID, length, stuffed instruction and parameters, CRC."""
    if not 0 <= packet_id <= 0xFE or packet_id == 0xFD:
        raise ValueError(f"packet ID must be 0-252 or 254 (broadcast), got {packet_id}")
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    if length > 0xFFFF:
        raise ValueError(f"packet too long ({length} bytes)")
    head = HEADER + bytes([packet_id]) + length.to_bytes(2, "little")
    crc = crc16(head + body)
    return head + body + crc.to_bytes(2, "little")


def encode_instruction(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet (see :func:`encode_packet`)."""
    return encode_packet(packet_id, instruction, params)


def encode_status(packet_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet from ``packet_id`` with the error byte ``error``."""
    return encode_packet(packet_id, INST_STATUS, bytes([error & 0xFF]) + bytes(params))


def decode_packet(data: bytes) -> Packet:
    """The one whole packet ``data`` holds.

    Raises
    ------
    ValueError
        If ``data`` is not exactly one valid packet (header, length, CRC).
    """
    return Parser.decode_one(data)


class Parser(FrameParser[Packet]):
    """Incremental decoder of Protocol 2.0 packets: feed it bytes as they come, it returns the
    whole packets (:class:`~gripper_env.hardware.bus.framing.FrameParser`: its resynchronising
    loop, :attr:`garbage_bytes`, :attr:`pending`, :meth:`reset`).

    Its header is ``FF FF FD 00`` (stuffing turns one in the payload into ``FF FF FD FD``).

    Attributes
    ----------
    bad_crc : int
        Packets dropped for their CRC (:attr:`bad_packets` under this protocol's name).
    """

    HEADER = HEADER
    HEAD_SIZE = 7  # FF FF FD 00 ID LEN_L LEN_H
    PROTOCOL = "Protocol 2.0"

    def _total_length(self, head: bytearray) -> int | None:
        packet_id = head[4]
        length = head[5] | head[6] << 8
        if packet_id > 0xFE or packet_id == 0xFD or not 3 <= length <= _MAX_LENGTH:
            return None
        return 7 + length

    def _check(self, packet: bytes) -> bool:
        return crc16(packet[:-2]) == packet[-2] | packet[-1] << 8

    def _decode(self, packet: bytes) -> Packet:
        body = unstuff(packet[7:-2])
        return Packet(packet[4], body[0], body[1:])

    @property
    def bad_crc(self) -> int:
        return self.bad_packets

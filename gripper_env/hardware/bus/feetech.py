"""Feetech SCS/STS packets: framing, checksum and an incremental parser.

A packet (Feetech's communication protocol manual; the same frame as Dynamixel Protocol 1.0)::

    FF FF | ID | LEN | INST or ERROR | PARAM... | CHECKSUM

``LEN`` is the number of parameters + 2; ``CHECKSUM = ~(ID + LEN + INST + sum(PARAM)) & 0xFF``.
An instruction packet carries an instruction (``INST_*``); a status packet (the servo's reply)
carries the servo's error byte in the same place: the bits of its ``status`` register
(:data:`ERRBIT_VOLTAGE` ... :data:`ERRBIT_OVERLOAD`, the bits the scservo SDK's
``getRxPacketError`` names). Multi-byte values are little-endian on the STS series (the SDK's
``PacketHandler(0)``; the older SCS series is big-endian).

Instructions: PING, READ, WRITE, REG_WRITE, ACTION, RESET (0x06, restore the factory table),
SYNC_READ (0x82: each listed servo answers with an ordinary status packet, in the order of the
list) and SYNC_WRITE (0x83, no reply).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "BROADCAST_ID",
    "ERRBIT_ANGLE",
    "ERRBIT_OVERCURRENT",
    "ERRBIT_OVERHEAT",
    "ERRBIT_OVERLOAD",
    "ERRBIT_VOLTAGE",
    "HEADER",
    "INST_ACTION",
    "INST_PING",
    "INST_READ",
    "INST_REG_WRITE",
    "INST_RESET",
    "INST_SYNC_READ",
    "INST_SYNC_WRITE",
    "INST_WRITE",
    "MAX_ID",
    "Packet",
    "Parser",
    "checksum",
    "decode_packet",
    "encode_instruction",
    "encode_packet",
    "encode_status",
]

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_RESET = 0x06
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83

# Error byte of a status packet: the servo's status register (65).
ERRBIT_VOLTAGE = 0x01  # input voltage outside the limits
ERRBIT_ANGLE = 0x02  # the position sensor (the SDK: "Angle sen error")
ERRBIT_OVERHEAT = 0x04  # temperature above the limit
ERRBIT_OVERCURRENT = 0x08  # current above the protection current (the SDK: "OverEle")
ERRBIT_OVERLOAD = 0x20  # load above the overload torque for the protection time


def checksum(body: bytes | bytearray) -> int:
    """``~sum(body) & 0xFF`` over ID, LEN, INST/ERROR and the parameters."""
    return ~sum(body) & 0xFF


@dataclass(frozen=True)
class Packet:
    """A decoded packet.

    Attributes
    ----------
    id : int
    code : int
        The instruction of an instruction packet, or the error byte of a status packet (the
        frame does not say which: the direction does).
    params : bytes
    """

    id: int
    code: int
    params: bytes = b""

    @property
    def instruction(self) -> int:
        return self.code

    @property
    def error(self) -> int:
        return self.code

    def encode(self) -> bytes:
        return encode_packet(self.id, self.code, self.params)


def encode_packet(packet_id: int, code: int, params: bytes = b"") -> bytes:
    """``FF FF ID LEN code params checksum``."""
    if not 0 <= packet_id <= 0xFE:
        raise ValueError(f"packet ID must be 0-253 or 254 (broadcast), got {packet_id}")
    length = len(params) + 2
    if length > 0xFF:
        raise ValueError(f"too many parameters ({len(params)}) for one packet")
    body = bytes([packet_id, length, code & 0xFF]) + bytes(params)
    return HEADER + body + bytes([checksum(body)])


def encode_instruction(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet."""
    return encode_packet(packet_id, instruction, params)


def encode_status(packet_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet from ``packet_id`` with the error byte ``error``."""
    return encode_packet(packet_id, error, params)


def decode_packet(data: bytes) -> Packet:
    """The one whole packet ``data`` holds.

    Raises
    ------
    ValueError
        If ``data`` is not exactly one valid packet.
    """
    parser = Parser()
    packets = parser.feed(data)
    if len(packets) != 1 or parser.pending or parser.garbage_bytes or parser.bad_checksum:
        raise ValueError(f"not one valid SCS/STS packet: {bytes(data).hex(' ')}")
    return packets[0]


class Parser:
    """Incremental decoder: feed it bytes as they come, it returns the whole packets.

    Bytes before a header ``FF FF`` and packets whose checksum fails are dropped: it
    resynchronises on the next header, searching from the byte after the failed packet's first
    byte (so a packet inside garbage is still found). Like the SDK, it skips a second ``FF``
    before the ID (``FF FF FF ID`` is a header preceded by noise).

    Attributes
    ----------
    garbage_bytes : int
        Bytes dropped while looking for a header (a failed packet's first byte included).
    bad_checksum : int
        Packets dropped for their checksum.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.garbage_bytes = 0
        self.bad_checksum = 0

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial packet (an inter-byte timeout)."""
        self.garbage_bytes += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray) -> list[Packet]:
        """Add ``data``; return the packets it completes, in order."""
        buf = self._buf
        buf += data
        packets: list[Packet] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                keep = 1 if buf[-1:] == b"\xff" else 0
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return packets
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < 4:
                return packets
            packet_id, length = buf[2], buf[3]
            if packet_id == 0xFF or length < 2:  # FF FF FF...: noise before the header
                self.garbage_bytes += 1
                del buf[:1]
                continue
            total = length + 4
            if len(buf) < total:
                return packets
            if checksum(buf[2 : total - 1]) != buf[total - 1]:
                self.bad_checksum += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            packets.append(Packet(packet_id, buf[4], bytes(buf[5 : total - 1])))
            del buf[:total]

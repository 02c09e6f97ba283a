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

from gripper_env.hardware.bus.framing import FrameParser

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
    return Parser.decode_one(data)


class Parser(FrameParser[Packet]):
    """Incremental decoder of SCS/STS packets: feed it bytes as they come, it returns the
    whole packets (:class:`~gripper_env.hardware.bus.framing.FrameParser`: its resynchronising
    loop, :attr:`garbage_bytes`, :attr:`pending`, :meth:`reset`).

    It skips a second ``FF`` before the ID, like the SDK (``FF FF FF ID`` is a header preceded by
    noise).

    Attributes
    ----------
    bad_checksum : int
        Packets dropped for their checksum (:attr:`bad_packets` under this protocol's name).
    """

    HEADER = HEADER
    HEAD_SIZE = 4  # FF FF ID LEN
    PROTOCOL = "SCS/STS"

    def _total_length(self, head: bytearray) -> int | None:
        packet_id, length = head[2], head[3]
        if packet_id == 0xFF or length < 2:  # FF FF FF...: noise before the header
            return None
        return length + 4

    def _check(self, packet: bytes) -> bool:
        return checksum(packet[2:-1]) == packet[-1]

    def _decode(self, packet: bytes) -> Packet:
        return Packet(packet[2], packet[4], packet[5:-1])

    @property
    def bad_checksum(self) -> int:
        return self.bad_packets

"""The incremental parser both bus protocols share: find a header, wait for the packet, check it.

A Feetech packet (:mod:`~gripper_env.hardware.bus.feetech`) and a Dynamixel 2.0 packet
(:mod:`~gripper_env.hardware.bus.dynamixel`) are both a fixed header, an ID, a length field
giving the rest of the packet's size, and a check at the end (a checksum, a CRC). Bytes come in
pieces and with noise between packets; :class:`FrameParser` holds what has come, returns each
whole packet once it is there and resynchronises on the next header after noise or a packet
that fails its check. A protocol says, by overriding its hooks, what its header is, how long a
packet is from its first bytes, whether a packet passes its check, and what it decodes to.
"""

from __future__ import annotations

from typing import ClassVar, Generic, TypeVar

__all__ = ["FrameParser"]

PacketT = TypeVar("PacketT")


class FrameParser(Generic[PacketT]):
    """Incremental decoder: feed it bytes as they come, it returns the whole packets.

    Bytes before a header and packets whose check fails are dropped: it resynchronises on the
    next header, searching from the byte after the failed packet's first byte (so a packet
    inside garbage is still found). Trailing bytes that could begin a header are kept.

    A protocol sets :attr:`HEADER` and :attr:`HEAD_SIZE` and overrides :meth:`_total_length`,
    :meth:`_check` and :meth:`_decode`.

    Attributes
    ----------
    garbage_bytes : int
        Bytes dropped while looking for a header (a failed packet's first byte included).
    bad_packets : int
        Packets dropped because their check (checksum, CRC) failed.
    """

    #: The bytes every packet begins with.
    HEADER: ClassVar[bytes] = b""
    #: How many bytes from the header's first one tell the packet's length.
    HEAD_SIZE: ClassVar[int] = 0
    #: The protocol's name, for messages.
    PROTOCOL: ClassVar[str] = ""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.garbage_bytes = 0
        self.bad_packets = 0

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial packet (an inter-byte timeout)."""
        self.garbage_bytes += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes | bytearray) -> list[PacketT]:
        """Add ``data``; return the packets it completes, in order."""
        buf = self._buf
        buf += data
        packets: list[PacketT] = []
        while True:
            start = buf.find(self.HEADER)
            if start < 0:
                keep = self._partial_header(buf)
                self.garbage_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return packets
            if start:
                self.garbage_bytes += start
                del buf[:start]
            if len(buf) < self.HEAD_SIZE:
                return packets
            total = self._total_length(buf)
            if total is None:  # the header's bytes, but not a packet's start
                self.garbage_bytes += 1
                del buf[:1]
                continue
            if len(buf) < total:
                return packets
            packet = bytes(buf[:total])
            if not self._check(packet):
                self.bad_packets += 1
                self.garbage_bytes += 1
                del buf[:1]
                continue
            packets.append(self._decode(packet))
            del buf[:total]

    @classmethod
    def decode_one(cls, data: bytes | bytearray) -> PacketT:
        """The one whole packet ``data`` holds.

        Raises
        ------
        ValueError
            If ``data`` is not exactly one valid packet (header, length, check), with nothing
            before or after it.
        """
        parser = cls()
        packets = parser.feed(data)
        if len(packets) != 1 or parser.pending or parser.garbage_bytes or parser.bad_packets:
            raise ValueError(f"not one valid {cls.PROTOCOL} packet: {bytes(data).hex(' ')}")
        return packets[0]

    def _partial_header(self, buf: bytearray) -> int:
        """How many trailing bytes of ``buf`` could begin a header."""
        for n in range(len(self.HEADER) - 1, 0, -1):
            if buf.endswith(self.HEADER[:n]):
                return n
        return 0

    def _total_length(self, head: bytearray) -> int | None:
        """The size of the packet ``head`` begins (header and check included).

        Parameters
        ----------
        head : bytearray
            At least :attr:`HEAD_SIZE` bytes, from the header's first one.

        Returns
        -------
        int or None
            ``None`` if these bytes cannot begin a packet (an impossible ID or length).
        """
        raise NotImplementedError

    def _check(self, packet: bytes) -> bool:
        """Whether the whole ``packet`` passes its checksum (CRC)."""
        raise NotImplementedError

    def _decode(self, packet: bytes) -> PacketT:
        """The packet the whole, checked ``packet`` holds."""
        raise NotImplementedError

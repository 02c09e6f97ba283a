"""Frames on the wire: ``COBS(seq | type | payload | crc16) + b"\\x00"``, and the stream decoder.

The twin of the firmware's ``gripper_protocol.h``.
"""

from __future__ import annotations

from dataclasses import dataclass

from gripper_env.hardware.protocol.constants import MAX_ENCODED_FRAME, MAX_PAYLOAD, MAX_RAW_FRAME
from gripper_env.hardware.protocol.errors import (
    CobsError,
    CrcError,
    FrameLengthError,
    ProtocolError,
    UnknownMessageTypeError,
)
from gripper_env.hardware.protocol.messages import (
    Configure,
    Estop,
    Heartbeat,
    Hello,
    Message,
    ProfileChunk,
    SetMode,
    Setpoint,
)
from gripper_env.hardware.protocol.reports import ErrorReport, Info, Status, Telemetry
from gripper_env.hardware.protocol.wire import (
    check_field,
    cobs_decode,
    cobs_encode,
    crc16_ccitt_false,
)

__all__ = [
    "MESSAGE_TYPES",
    "DecoderStats",
    "FrameDecoder",
    "FrameSplitter",
    "ReceivedFrame",
    "decode_frame",
    "decode_payload",
    "encode_frame",
    "encode_raw_frame",
]

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


def encode_raw_frame(seq: int, type_id: int, payload: bytes) -> bytes:
    """Frame an arbitrary payload: ``COBS(seq | type | payload | crc16 LE) + b"\\x00"``.

    Raises
    ------
    FieldValueError
        If ``seq`` or ``type_id`` is not a u8.
    FrameLengthError
        If the payload exceeds :data:`MAX_PAYLOAD` bytes.
    """
    check_field("frame", "seq", "B", seq)
    check_field("frame", "type", "B", type_id)
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
    damaged : int
        Frames dropped because bytes of them were lost before the decoder
        (:meth:`FrameSplitter.abort_frame`).
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
    damaged: int = 0
    bad_message: int = 0
    lost: int = 0
    gaps: int = 0

    @property
    def rejected(self) -> int:
        """Frames rejected for any reason."""
        return (
            self.bad_cobs
            + self.bad_crc
            + self.truncated
            + self.oversized
            + self.damaged
            + self.bad_message
        )


class FrameSplitter:
    """Split an arbitrary byte stream into CRC-checked frames; never raises on bad input.

    Feed it whatever the line delivers; it splits on ``0x00``, drops frames that are not valid
    COBS, are too short or too long or fail the CRC, counts each reason in :attr:`stats`, keeps
    the last reason in :attr:`last_error`, and resynchronises at the next delimiter. The
    firmware's stream decoder (``gripper_protocol.h``) works the same way; its Python twin uses
    this class.

    Parameters
    ----------
    synced : bool
        ``True`` (default) treats the first bytes as the start of a frame. ``False`` discards
        everything up to the first ``0x00``: use it when joining a stream mid-frame.
    max_encoded : int
        Longest accepted frame in bytes, without the delimiter.

    Attributes
    ----------
    last_gap : int
        Frames missing before the last valid frame.
    """

    def __init__(self, *, synced: bool = True, max_encoded: int = MAX_ENCODED_FRAME) -> None:
        self.stats = DecoderStats()
        self.last_error: ProtocolError | None = None
        self.last_gap = 0
        self._max = max_encoded
        self._buffer = bytearray()
        self._overflow = False
        self._damaged = False
        self._synced = synced
        self._last_seq: int | None = None

    def reset_sequence(self) -> None:
        """Forget the last sequence number (after a device reset): no gap is counted next."""
        self._last_seq = None

    def abort_frame(self) -> None:
        """Bytes were lost before the next byte fed (a full receive buffer): the frame they
        belonged to is dropped at its delimiter whatever its CRC says (counted as ``damaged``)."""
        self._damaged = True

    def forgive_last_gap(self) -> None:
        """Take the last gap back out of the counts (the sender started a new sequence)."""
        if self.last_gap:
            self.stats.lost -= self.last_gap
            self.stats.gaps -= 1
        self.last_gap = 0

    def split(self, data: bytes) -> list[tuple[int, int, bytes, int]]:
        """Consume ``data``; return the CRC-valid frames it completed, in order, as
        ``(seq, type, payload, gap)`` (``gap``: frames missing before this one)."""
        out: list[tuple[int, int, bytes, int]] = []
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
            frame = self._finish()
            if frame is not None:
                out.append(frame)
                self._accepted(*frame)
            start = end + 1

    def _accepted(self, seq: int, type_id: int, payload: bytes, gap: int) -> None:
        """Called on each valid frame as it completes (subclasses parse it)."""

    def _reject(self, counter: str, error: ProtocolError, n: int) -> None:
        setattr(self.stats, counter, getattr(self.stats, counter) + 1)
        self.stats.discarded_bytes += n
        self.last_error = error

    def _finish(self) -> tuple[int, int, bytes, int] | None:
        encoded = bytes(self._buffer)
        overflow = self._overflow
        damaged = self._damaged
        self._buffer.clear()
        self._overflow = False
        self._damaged = False
        if damaged:
            self._reject(
                "damaged",
                FrameLengthError("bytes of the frame were lost before the decoder"),
                len(encoded),
            )
            return None
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
        self.last_gap = gap
        self._last_seq = seq
        return seq, type_id, payload, gap


class FrameDecoder(FrameSplitter):
    """Turn an arbitrary byte stream into messages; never raises on bad input.

    A :class:`FrameSplitter` that also parses each frame's payload: frames with an unknown
    type or a payload that does not fit it are dropped too (counted as ``bad_message``). Its
    parameters are :class:`FrameSplitter`'s.
    """

    def __init__(self, *, synced: bool = True, max_encoded: int = MAX_ENCODED_FRAME) -> None:
        super().__init__(synced=synced, max_encoded=max_encoded)
        self._received: list[ReceivedFrame] = []

    def feed(self, data: bytes) -> list[ReceivedFrame]:
        """Consume ``data`` and return the messages it completed, in order."""
        self.split(data)
        out, self._received = self._received, []
        return out

    def _accepted(self, seq: int, type_id: int, payload: bytes, gap: int) -> None:
        try:
            message = decode_payload(type_id, payload)
        except ProtocolError as exc:
            self.stats.bad_message += 1
            self.last_error = exc
            return
        self.stats.messages += 1
        self._received.append(ReceivedFrame(seq, message, gap))

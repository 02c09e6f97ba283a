"""Host side of the gripper's binary serial protocol (the firmware's ``gripper_protocol.h``).

A frame on the wire is ``COBS(seq | type | payload | crc16) + b"\\x00"``:

* ``seq`` (u8) counts frames per direction and wraps; a jump reveals lost frames.
* ``type`` (u8) is a message type id: host -> device below ``0x80``, device -> host above.
* ``payload`` is the message, packed little-endian field by field (at most 240 bytes).
* ``crc16`` is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, xorout 0) over
  ``seq | type | payload``, little-endian.

The full specification, with every byte layout, unit, the handshake, watchdog and ESTOP
semantics, is ``firmware/PROTOCOL.md``. The package holds, each in its module (all importable
from here):

* :mod:`~gripper_env.hardware.protocol.constants`: the version, sizes and enumerations;
* :mod:`~gripper_env.hardware.protocol.errors`: what decoding and encoding raise;
* :mod:`~gripper_env.hardware.protocol.wire`: CRC-16, COBS and the field range checks;
* :mod:`~gripper_env.hardware.protocol.messages`: the message base and the host -> device
  messages;
* :mod:`~gripper_env.hardware.protocol.reports`: the device -> host messages;
* :mod:`~gripper_env.hardware.protocol.framing`: frames and the stream decoder.

Examples
--------
>>> frame = encode_frame(0, Hello())
>>> decoder = FrameDecoder()
>>> [received.message for received in decoder.feed(frame)]
[Hello(protocol_version=1)]
"""

from gripper_env.hardware.protocol.constants import (
    CDEG_NONE,
    MAX_ENCODED_FRAME,
    MAX_PAYLOAD,
    MAX_RAW_FRAME,
    PROFILE_CHUNK_MAX_SAMPLES,
    PROTOCOL_VERSION,
    TELEMETRY_MAX_SAMPLES,
    AntiWindup,
    ErrorCode,
    Fault,
    Mode,
    SampleFlag,
    StatusFlag,
)
from gripper_env.hardware.protocol.errors import (
    CobsError,
    CrcError,
    FieldValueError,
    FrameLengthError,
    PayloadLengthError,
    ProtocolError,
    UnknownMessageTypeError,
)
from gripper_env.hardware.protocol.framing import (
    MESSAGE_TYPES,
    DecoderStats,
    FrameDecoder,
    FrameSplitter,
    ReceivedFrame,
    decode_frame,
    decode_payload,
    encode_frame,
    encode_raw_frame,
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
from gripper_env.hardware.protocol.reports import (
    ErrorReport,
    Info,
    Status,
    Telemetry,
    TelemetrySample,
)
from gripper_env.hardware.protocol.wire import cobs_decode, cobs_encode, crc16_ccitt_false

__all__ = [
    "CDEG_NONE",
    "MAX_ENCODED_FRAME",
    "MAX_PAYLOAD",
    "MAX_RAW_FRAME",
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
    "FrameSplitter",
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

"""Link to the real gripper: the binary serial protocol spoken with the Mega 2560 firmware.

:mod:`gripper_env.hardware.protocol` is the Python twin of ``firmware/gripper_core.h``; the
wire format is specified in ``firmware/PROTOCOL.md``.
"""

from gripper_env.hardware.protocol import (
    PROTOCOL_VERSION,
    Configure,
    ErrorReport,
    Estop,
    FrameDecoder,
    Heartbeat,
    Hello,
    Info,
    Message,
    ProfileChunk,
    ProtocolError,
    SetMode,
    Setpoint,
    Status,
    Telemetry,
    TelemetrySample,
    decode_frame,
    encode_frame,
)

__all__ = [
    "PROTOCOL_VERSION",
    "Configure",
    "ErrorReport",
    "Estop",
    "FrameDecoder",
    "Heartbeat",
    "Hello",
    "Info",
    "Message",
    "ProfileChunk",
    "ProtocolError",
    "SetMode",
    "Setpoint",
    "Status",
    "Telemetry",
    "TelemetrySample",
    "decode_frame",
    "encode_frame",
]

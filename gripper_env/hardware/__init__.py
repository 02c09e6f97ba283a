"""Link to the real gripper: the binary serial protocol spoken with the Mega 2560 firmware.

:mod:`gripper_env.hardware.protocol` is the Python twin of ``firmware/gripper_core.h``; the
wire format is specified in ``firmware/PROTOCOL.md``. The rest, imported from its module:

* :mod:`~gripper_env.hardware.device`: :class:`GripperDevice`, the host's session with a board;
* :mod:`~gripper_env.hardware.calibration`: the two-point ADC calibration and its file;
* :mod:`~gripper_env.hardware.experiment`: run a profile host-in-the-loop and record it;
* :mod:`~gripper_env.hardware.firmware`: the board's state machine in Python;
* :mod:`~gripper_env.hardware.virtual`: the virtual board on a pty
  (``python -m gripper_env.hardware.virtual``).
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

"""Link to the real gripper: the binary serial protocol spoken with the Mega 2560 firmware.

:mod:`gripper_env.hardware.protocol` is the Python twin of the firmware's protocol unit; the
wire format is specified in ``firmware/PROTOCOL.md`` and its message layouts described once in
``firmware/protocol.toml`` (:mod:`~gripper_env.hardware.layouts`). The rest, imported from its
module:

* the host's side of a board:

  * :mod:`~gripper_env.hardware.host.device`: :class:`GripperDevice`, the host's session with a
    board, over :mod:`~gripper_env.hardware.host.serial_port` (the pyserial port), with
    :mod:`~gripper_env.hardware.host.command_log` (what the board reported lost, what to resend);
  * :mod:`~gripper_env.hardware.host.errors`: :class:`DeviceError` and its kinds;
  * :mod:`~gripper_env.hardware.host.telemetry`: telemetry as arrays on one device clock;
  * :mod:`~gripper_env.hardware.host.configuration`: the CONFIGURE for gains and a calibration;
  * :mod:`~gripper_env.hardware.host.calibration`: the two-point ADC calibration and its file;
  * :mod:`~gripper_env.hardware.host.experiment`: run a profile host-in-the-loop and record it;

* the board without hardware:

  * :mod:`~gripper_env.hardware.twin.firmware`: the board's state machine in Python, with
    :mod:`~gripper_env.hardware.safety` and
    :mod:`~gripper_env.hardware.twin.firmware_config`;
  * :mod:`~gripper_env.hardware.twin.rig`: the simulated gripper, and the twin wired to it;
  * :mod:`~gripper_env.hardware.virtual`: the virtual board on a pty
    (``python -m tuners.rig.virtual``; command line in
    :mod:`~tuners.rig.virtual`);
  * :mod:`~gripper_env.hardware.emulator.board`: the compiled firmware under simavr
    (:mod:`~gripper_env.hardware.emulator.mega2560`, built by
    :mod:`~gripper_env.hardware.emulator.build`),
    on a pty too (``python -m tuners.rig.virtual --emulated``);
  * :mod:`~gripper_env.hardware.emulator.scripted`: a scripted host on emulated time, and the
    agreement of
    the emulated board, the Python twin and the simulation core;
  * :mod:`~gripper_env.hardware.emulator.link_fuzz`: fuzzed host traffic against the compiled image.
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

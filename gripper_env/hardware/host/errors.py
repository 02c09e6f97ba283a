"""What can go wrong talking to the board: :class:`DeviceError` and its kinds.

=====================  ============================================================================
:class:`DeviceTimeout`  no valid answer in time (a silent device)
:class:`LinkError`      answers arrived but were corrupted (CRC, COBS, truncated frames)
:class:`CommandLost`    the board does not hold a command the host sent, after every retry
:class:`DeviceReset`    the board restarted (it lost the session: NO_SESSION, unsolicited INFO)
:class:`PortVanished`   the serial port disappeared (cable pulled)
:class:`DeviceRefused`  the board answered ERROR (``VersionMismatch`` for a protocol mismatch)
:class:`DeviceFault`    a fault latched on the board (watchdog, ESTOP, sensor, numeric)
=====================  ============================================================================

:func:`fault_error` and :func:`refusal` word the exception for a latched fault and for an ERROR
answer.
"""

from __future__ import annotations

from dataclasses import fields

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.protocol import ErrorCode, Fault

__all__ = [
    "CommandLost",
    "DeviceError",
    "DeviceFault",
    "DeviceRefused",
    "DeviceReset",
    "DeviceTimeout",
    "LinkError",
    "PortVanished",
    "VersionMismatch",
    "fault_error",
    "fault_names",
    "refusal",
]

ERROR_NAMES = {v: k for k, v in vars(ErrorCode).items() if not k.startswith("_")}
FAULT_BITS = {"WATCHDOG": Fault.WATCHDOG, "ESTOP": Fault.ESTOP, "NUMERIC": Fault.NUMERIC}
FAULT_BITS["SENSOR"] = Fault.SENSOR


def fault_names(bits: int) -> str:
    """``"WATCHDOG+ESTOP"`` for fault bits (``"none"`` for 0)."""
    names = [name for name, bit in FAULT_BITS.items() if bits & bit]
    return "+".join(names) or "none"


class DeviceError(Exception):
    """Base class of everything that can go wrong talking to the board."""


class DeviceTimeout(DeviceError, TimeoutError):
    """No valid answer arrived in time."""


class LinkError(DeviceError, proto.ProtocolError):
    """Frames arrived but failed their checks (CRC, COBS, length), so no valid answer came."""


class CommandLost(DeviceError):
    """A command did not take on the board (a setpoint it does not hold, a mode it is not in)
    after every retry: lost on the way each time."""


class DeviceReset(DeviceError):
    """The board restarted and lost its session, mode and configuration."""


class PortVanished(DeviceError, ConnectionError):
    """The serial port went away (unplugged cable, closed pseudo-terminal)."""


class DeviceRefused(DeviceError):
    """The board answered a command with ERROR.

    Attributes
    ----------
    code : int
        :class:`~gripper_env.hardware.protocol.ErrorCode`.
    detail : int
        The code-specific detail (field index, fault bits, version...).
    """

    def __init__(self, message: str, code: int, detail: int) -> None:
        super().__init__(message)
        self.code = code
        self.detail = detail


class VersionMismatch(DeviceRefused):
    """The board speaks another protocol version."""


class DeviceFault(DeviceError):
    """A fault latched on the board: it made a safe stop (idle, jaw open).

    Attributes
    ----------
    faults : int
        The latched :class:`~gripper_env.hardware.protocol.Fault` bits.
    """

    def __init__(self, message: str, faults: int) -> None:
        super().__init__(message)
        self.faults = faults


_FAULT_REASONS = {
    "WATCHDOG": "no host frame for 500 ms",
    "ESTOP": "emergency stop",
    "SENSOR": "potentiometer reading at a rail",
    "NUMERIC": "non-finite PID value",
}


def fault_error(port: str, faults: int) -> DeviceFault:
    """The :class:`DeviceFault` for fault bits ``faults`` latched on the board at ``port``."""
    names = fault_names(faults)
    reasons = ", ".join(_FAULT_REASONS[n] for n in names.split("+") if n in _FAULT_REASONS)
    return DeviceFault(
        f"device on {port} made a safe stop (idle, jaw open): fault {names} ({reasons or 'fault'})",
        faults,
    )


def version_mismatch(port: str, version: int) -> VersionMismatch:
    """The board at ``port`` speaks protocol ``version``, not this host's."""
    return VersionMismatch(
        f"device on {port} speaks protocol version {version}, this host speaks "
        f"{proto.PROTOCOL_VERSION}: update the firmware or the host",
        ErrorCode.VERSION_MISMATCH,
        version,
    )


def refusal(port: str, msg: proto.Message, err: proto.ErrorReport) -> DeviceRefused:
    """The exception for the ERROR ``err`` with which the board at ``port`` answered ``msg``."""
    if err.code == ErrorCode.VERSION_MISMATCH:
        return version_mismatch(port, err.detail)
    name = type(msg).__name__.upper()
    code = ERROR_NAMES.get(err.code, f"code {err.code}")
    detail = ""
    if err.code == ErrorCode.BAD_VALUE and isinstance(msg, proto.Configure):
        field_name = [f.name for f in fields(msg)][err.detail]
        detail = f": field {field_name}={getattr(msg, field_name)!r} refused"
    elif err.code == ErrorCode.FAULT_LATCHED:
        detail = f": fault {fault_names(err.detail)} latched (set IDLE to acknowledge)"
    return DeviceRefused(f"device refused {name}: {code}{detail}", err.code, err.detail)

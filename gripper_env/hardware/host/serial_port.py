"""The byte pipe to the board: a pyserial port whose failures say what happened.

Opening, reading and writing raise :class:`~gripper_env.hardware.host.errors.PortVanished` when the
port cannot be opened or goes away (cable pulled, pseudo-terminal closed) and
:class:`~gripper_env.hardware.host.errors.DeviceTimeout` when the line is blocked;
:class:`~gripper_env.hardware.host.device.GripperDevice` speaks the protocol over it.
"""

from __future__ import annotations

import os
import time
from typing import Any

import serial
import serial.tools.list_ports

from gripper_env.hardware.host.errors import DeviceTimeout, PortVanished

__all__ = ["close_port", "list_ports", "open_port", "read_bytes", "write_bytes"]


def list_ports() -> list[tuple[str, str]]:
    """Serial ports that may be a gripper board: ``(device, description)``, Arduinos first."""
    ports = []
    for p in serial.tools.list_ports.comports():
        text = f"{p.description or ''} {p.manufacturer or ''}".strip()
        arduino = "arduino" in text.lower() or (p.vid == 0x2341)  # Arduino's USB vendor id
        ports.append((not arduino, p.device, text or "serial port"))
    return [(device, text) for _, device, text in sorted(ports)]


def open_port(port: str, baudrate: int) -> Any:
    """Open ``port`` (a device path or a pyserial URL) at ``baudrate``; reads poll every 10 ms."""
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=0.01, write_timeout=1.0)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortVanished(f"cannot open serial port {port!r}: {exc}") from None


def close_port(ser: Any) -> None:
    """Close an open port, ignoring the errors of one that is already gone."""
    try:
        ser.close()
    except (serial.SerialException, OSError):
        pass


def _vanished(ser: Any, port: str, exc: BaseException) -> PortVanished:
    close_port(ser)
    gone = "" if os.path.exists(port) else f" ({port} no longer exists)"
    return PortVanished(f"serial port {port} went away{gone}: {exc}")


def write_bytes(ser: Any, port: str, data: bytes) -> None:
    """Write ``data`` to the open port ``ser`` (named ``port`` in errors)."""
    try:
        ser.write(data)
    except serial.SerialTimeoutException:
        raise DeviceTimeout(f"cannot write to {port}: the line is blocked") from None
    except (serial.SerialException, OSError) as exc:
        raise _vanished(ser, port, exc) from None


def read_bytes(ser: Any, port: str, timeout_s: float) -> bytes:
    """What arrived on ``ser``, waiting up to ``timeout_s`` for the first byte (``b""`` if none)."""
    deadline = time.monotonic() + timeout_s
    try:
        while True:
            waiting = ser.in_waiting
            data: bytes
            if waiting or timeout_s <= 0:
                data = ser.read(waiting) if waiting else b""
            else:
                data = ser.read(1)
                if data and ser.in_waiting:
                    data += ser.read(ser.in_waiting)
            if data or time.monotonic() >= deadline:
                return data
    except (serial.SerialException, OSError) as exc:
        raise _vanished(ser, port, exc) from None

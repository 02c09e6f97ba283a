"""What the rig's command lines share: port arguments, opening the device, error handling.

Every rig command (``tuners.rig.calibrate``, ``tuners.rig.record``, ``tuners.rig.deploy``) takes
``--port`` (a serial device, a pyserial URL, or the path printed by
``python -m tuners.rig.virtual``), ``--boot-wait`` and ``--timeout``, and turns every
expected failure into one line on stderr and exit status 2 (no traceback); the
notes an error carries (where a failed run's partial log is) follow on their own lines.
``--port list`` prints the serial ports that look like a gripper board.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from gripper_env.hardware.host.calibration import CalibrationError, calibrations_dir
from gripper_env.hardware.host.errors import DeviceError
from gripper_env.hardware.host.serial_port import list_ports
from gripper_env.io.config import ConfigError

__all__ = ["EXIT_ERROR", "add_device_arguments", "positive_float", "run_cli"]

EXIT_ERROR = 2


def positive_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text}")
    return value


def add_device_arguments(parser: argparse.ArgumentParser, calibration: bool = True) -> None:
    """Add ``--port``, ``--boot-wait``, ``--timeout`` (and ``--calibration``)."""
    parser.add_argument(
        "--port",
        required=True,
        help="serial port of the board (/dev/ttyACM0, COM3, a pyserial URL, or the pty printed "
        "by 'python -m tuners.rig.virtual'); 'list' prints the candidates",
    )
    parser.add_argument(
        "--boot-wait",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="seconds to let the board boot after opening the port (opening resets a Mega); "
        "0 for the virtual device (default: 2)",
    )
    parser.add_argument(
        "--timeout",
        type=positive_float,
        default=0.5,
        metavar="S",
        help="seconds to wait for each answer from the board (default: 0.5)",
    )
    if calibration:
        parser.add_argument(
            "--calibration",
            default=None,
            metavar="FILE",
            help="calibration file from 'python -m tuners.rig.calibrate', refused if it is "
            "another board's (default: $GRIPPER_CALIBRATION, else the board's own, found by its "
            f"device id in {calibrations_dir()})",
        )


def given_calibration(args: argparse.Namespace) -> tuple[Path | None, str]:
    """The calibration file the user named, and what named it: ``--calibration``, else
    ``$GRIPPER_CALIBRATION``; ``(None, "")`` for the board's own (found after the handshake)."""
    if getattr(args, "calibration", None):
        return Path(args.calibration).expanduser(), "--calibration"
    env = os.environ.get("GRIPPER_CALIBRATION")
    if env:
        return Path(env).expanduser(), "$GRIPPER_CALIBRATION"
    return None, ""


def run_cli(
    parser: argparse.ArgumentParser,
    body: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None = None,
) -> int:
    """Parse, run ``body``, and turn expected failures into one line on stderr and status 2."""
    args = parser.parse_args(argv)
    if getattr(args, "port", None) == "list":
        ports = list_ports()
        for device, text in ports:
            print(f"{device}\t{text}")
        if not ports:
            print("no serial ports found", file=sys.stderr)
        return 0
    try:
        return body(args)
    except KeyboardInterrupt as exc:
        _print_notes(exc)
        print(f"{parser.prog}: interrupted; the board was stopped", file=sys.stderr)
        return 130
    except (DeviceError, CalibrationError, ConfigError, ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        _print_notes(exc)
        return EXIT_ERROR


def _print_notes(exc: BaseException) -> None:
    for note in getattr(exc, "__notes__", ()):
        print(note, file=sys.stderr)

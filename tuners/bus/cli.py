"""What the bus-servo commands share: the servo's arguments and the error handling.

``python -m tuners.bus.record`` and ``python -m tuners.bus.deploy`` take ``--port`` (a USB
adapter such as the Feetech URT-1 or the ROBOTIS U2D2, or the path ``python -m tuners.bus.virtual``
prints), ``--model`` (the servo family or an identified model file), ``--id`` and ``--baudrate``,
and turn every expected failure (a bus error, a refused register set, a bad file) into one line
on stderr and exit status 2, with the servo's torque off.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from gripper_env.hardware.bus.gripper import FACTORY_BAUD
from gripper_env.hardware.bus.link import BusError
from gripper_env.io.config import ConfigError

__all__ = ["EXIT_ERROR", "add_servo_arguments", "run_cli"]

EXIT_ERROR = 2


def add_servo_arguments(parser: argparse.ArgumentParser, model: bool = True) -> None:
    """Add ``--port``, ``--id``, ``--baudrate`` (and ``--model``)."""
    parser.add_argument(
        "--port",
        required=True,
        help="serial port of the bus adapter (/dev/ttyUSB0, COM3) or the pty printed by "
        "'python -m tuners.bus.virtual'",
    )
    if model:
        parser.add_argument(
            "--model",
            default="sts3215",
            help="the servo: sts3215, xl330, xl430, or an identified model file "
            "(python -m tuners.bus.identify); default sts3215",
        )
    parser.add_argument("--id", type=int, default=1, help="the servo's ID on the bus (default 1)")
    parser.add_argument(
        "--baudrate",
        type=int,
        default=None,
        help="bus baud rate (default: the family's factory rate, "
        + ", ".join(f"{k} {v}" for k, v in FACTORY_BAUD.items())
        + ")",
    )


def run_cli(
    parser: argparse.ArgumentParser,
    body: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None = None,
) -> int:
    """Parse, run ``body``, and turn expected failures into one line on stderr and status 2."""
    args = parser.parse_args(argv)
    try:
        return body(args)
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted; the servo's torque was turned off", file=sys.stderr)
        return 130
    except (BusError, ConfigError, ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR

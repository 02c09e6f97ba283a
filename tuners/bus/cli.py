"""What the bus-servo commands share: the servo's arguments, opening it, signals and errors.

``python -m tuners.bus.calibrate``, ``record`` and ``deploy`` take ``--port`` (a USB adapter
such as the Feetech URT-1 or the ROBOTIS U2D2, or the path ``python -m tuners.bus.virtual``
prints), ``--id`` (required: a servo on a shared bus is never guessed; without it, or with an
ID that does not answer, the command lists the servos that answer and stops), ``--baudrate``
and ``--keep-torque``.

:func:`run_cli` runs a command's body with SIGINT and SIGTERM deferred to the end of the bus
transaction under way (:mod:`gripper_env.hardware.bus.interrupts`); the servo is restored by
its :class:`~gripper_env.hardware.bus.gripper.BusGripper` on the way out, and every failure ends
in one line on stderr saying what happened and what the servo reads back now:

* exit 2: bad input, or a refusal before anything was written (no or a wrong ``--id``, another
  model, a calibration that is not the servo's, a plan outside the jaw's range, registers that
  fail the gate);
* exit 1: the bus or the servo failed during the run (no reply after the retries, an error bit
  such as an overload, the port gone);
* exit 130 (SIGINT) or 143 (SIGTERM): interrupted.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from gripper_env.hardware.bus.gripper import (
    FACTORY_BAUD,
    MODEL_NAMES,
    BusCalibrationError,
    BusGripper,
    BusSelectError,
)
from gripper_env.hardware.bus.interrupts import BusInterrupted, handle_signals
from gripper_env.hardware.bus.link import BusError, BusModelError, BusPortError, BusPortLostError
from gripper_env.io.config import ConfigError
from gripper_env.model.bus_calibration import JawCalibration, read_jaw_file
from gripper_env.model.bus_servo import BusServoModel

__all__ = [
    "EXIT_ERROR",
    "EXIT_FAILURE",
    "BusArgumentParser",
    "add_servo_arguments",
    "load_jaw",
    "open_gripper",
    "output_folder",
    "run_cli",
    "servo_id",
]

#: Bad input, or a refusal before anything was written.
EXIT_ERROR = 2
#: The bus or the servo failed during the run.
EXIT_FAILURE = 1


class BusArgumentParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (naming the option) and exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def servo_id(text: str) -> int:
    """``--id``: a servo ID, 0..252."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a servo ID 0..252, got {text!r}") from None
    if not 0 <= value <= 252:
        raise argparse.ArgumentTypeError(f"expected a servo ID 0..252, got {text!r}")
    return value


def add_servo_arguments(
    parser: argparse.ArgumentParser, model: bool = True, keep_torque: bool = True
) -> None:
    """Add ``--port``, ``--id``, ``--baudrate`` (and ``--model``, ``--keep-torque``)."""
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
    parser.add_argument(
        "--id",
        type=servo_id,
        default=None,
        help="the gripper servo's ID on the bus (required: run without it to list the servos "
        "that answer; an SO-101's gripper is 6)",
    )
    parser.add_argument(
        "--baudrate",
        type=int,
        default=None,
        help="bus baud rate (default: the family's factory rate, "
        + ", ".join(f"{k} {v}" for k, v in FACTORY_BAUD.items())
        + ")",
    )
    if keep_torque:
        parser.add_argument(
            "--keep-torque",
            action="store_true",
            help="leave the torque on at the end (default: as it was found)",
        )


def output_folder(path: Path, option: str = "--out") -> Path:
    """``path`` as an output folder, checked before any work (a ValueError naming ``option`` if
    it is a file, lies under one or cannot be written). It is not created here: the first file
    written into it makes it, so a command refused later (a port that does not open) leaves
    nothing behind."""
    from tuners.cli import check_output_folder

    check_output_folder(path, option)
    return path


def load_jaw(path: str | None, model: BusServoModel, servo: int | None) -> JawCalibration:
    """The jaw calibration of a command: ``--jaw FILE``, else the model's own; checked against
    the model's family and ``--id``.

    Raises
    ------
    ValueError
        None at all, another family, another servo, or a file and a model that disagree.
    """
    from_file = None if path is None else read_jaw_file(path)
    cal = from_file or model.calibration
    if cal is None:
        raise ValueError(
            "--jaw is required: the jaw's closed and open positions on this servo (python -m "
            "tuners.bus.calibrate writes the file); the shipped model's angles are the virtual "
            "servo's, never a real servo's"
        )
    if from_file is not None and model.calibration not in (None, from_file):
        raise ValueError(
            f"--jaw {path} is not the jaw calibration the model {model.name!r} was identified "
            "with: use one calibration throughout (or calibrate and record again)"
        )
    if cal.family != model.family:
        raise ValueError(f"--jaw: the calibration is of a {cal.family}, not a {model.family}")
    if cal.servo_id is not None and servo is not None and cal.servo_id != servo:
        raise ValueError(f"--id {servo}: the jaw calibration was taken on servo {cal.servo_id}")
    if cal.arm_joint and not cal.risk_arm_joint:
        where = f"--jaw {path}" if from_file is not None else f"the model {model.name!r}"
        raise ValueError(
            f"{where} is a calibration of LeRobot's motor {cal.motor!r}, an arm joint, not the "
            "gripper: refusing to drive it (calibrate the gripper's motor, or calibrate this one "
            "again with --risk-arm-joint if you mean it)"
        )
    return cal


def open_gripper(
    args: argparse.Namespace, model: BusServoModel, calibration: JawCalibration
) -> BusGripper:
    """Open the servo of ``--port``, ``--id``, ``--baudrate`` (:class:`BusGripper`: found by
    its ID, its calibration checked, its registers snapshot), print what answered, and keep it
    in ``args.gripper`` for :func:`run_cli`'s last word."""
    jaw = BusGripper(args.port, model, args.id, baudrate=args.baudrate, calibration=calibration)
    args.gripper = jaw
    jaw.keep_torque = bool(getattr(args, "keep_torque", False))
    ids = sorted(s.servo_id for s in jaw.bus_servos)
    name = MODEL_NAMES.get(jaw.servo_registers.model_number, jaw.model.family)
    others = f"one of {len(ids)} servos answering (IDs {', '.join(map(str, ids))})"
    print(
        f"servo {jaw.servo_id} on {jaw.port}: {name}, {others if len(ids) > 1 else 'alone'}; "
        f"jaw {jaw.calibration.describe()}",
        flush=True,
    )
    return jaw


def _last_word(args: argparse.Namespace | None, exc: BaseException) -> str:
    """The exception's notes (the servo's state read back), or what is known without them."""
    notes = list(getattr(exc, "__notes__", []))
    if notes:
        return "; ".join(notes)
    jaw = getattr(args, "gripper", None)
    if jaw is None:
        return "nothing was written to the servo"
    if jaw.restored is not None:
        return jaw.restored.describe()
    return "the servo's state is unknown"


def run_cli(
    parser: argparse.ArgumentParser,
    body: Callable[[argparse.Namespace], int],
    argv: Sequence[str] | None = None,
) -> int:
    """Parse, run ``body`` with signals deferred between transactions, and turn every failure
    into one line on stderr (see the module for the exit statuses)."""
    args: Any = parser.parse_args(argv)
    prog = parser.prog

    def say(text: str) -> None:
        print(f"{prog}: {text}", file=sys.stderr, flush=True)

    with handle_signals():
        try:
            return body(args)
        except BusInterrupted as exc:
            say(f"interrupted ({exc.name}); {_last_word(args, exc)}")
            return exc.exit_status
        except KeyboardInterrupt as exc:  # outside the main thread: no deferral
            say(f"interrupted; {_last_word(args, exc)}")
            return 130
        except BusSelectError as exc:
            say(f"error: --id: {exc}; {_last_word(args, exc)}")
            return EXIT_ERROR
        except BusPortLostError as exc:
            say(f"error: {exc}; {_last_word(args, exc)}")
            return EXIT_FAILURE
        except (BusCalibrationError, BusModelError, BusPortError) as exc:
            say(f"error: {exc}; {_last_word(args, exc)}")
            return EXIT_ERROR
        except BusError as exc:
            say(f"error: {exc}; {_last_word(args, exc)}")
            return EXIT_FAILURE
        except (ConfigError, ValueError, OSError) as exc:
            say(f"error: {exc}; {_last_word(args, exc)}")
            return EXIT_ERROR

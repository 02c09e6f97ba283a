"""``python -m tuners.bus.calibrate``: the gripper's jaw on its servo, as the owner has it.

Writes the jaw calibration that ``python -m tuners.bus.record`` and ``deploy`` take (``--jaw``):
where the jaw is fully closed and fully open, in the servo's own encoder ticks, and the
calibration the servo holds (homing offset, min/max position limits, operating mode, drive
mode, maximum torque limit), which every later command checks before it writes a byte. The
servo of ``--id`` is found on the bus first (a broadcast ping; nothing is sent to the others).
Three ways to give the positions:

* **by hand** (default): the servo's torque goes off (read back); move the jaw fully closed and
  press Enter, then fully open and press Enter. The torque ends as it was found (if it was on,
  the servo drives back to the goal it held);
* **given**: ``--closed-ticks N --open-ticks N`` (no prompt; nothing is written to the servo);
* **LeRobot's calibration file** of the arm (``--lerobot
  ~/.cache/huggingface/lerobot/calibration/robots/so101_follower/NAME.json``, motor
  ``--motor gripper``), read as data: its ``range_min`` and ``range_max`` are the jaw's ends
  (LeRobot's 0 % is taken as closed: ``range_min``, or ``range_max`` with ``drive_mode`` 1;
  ``--closed-at`` says otherwise), and its ``id``, ``homing_offset`` and range must be what the
  servo holds. Only the motor named ``gripper`` is taken: another (``--motor shoulder_pan``) is
  an arm joint, refused before the port is opened unless ``--risk-arm-joint`` says the owner
  means it (the calibration then says so, and every later command with it).

Positions beyond the servo's own position limits are brought inside them (the servo never gets
a goal outside). Nothing of the servo's calibration is ever written. The servo runs position
control, or on an XL330 current-based position control (operating mode 5, the Koch gripper's as
LeRobot's ``koch_follower`` configures it): the mode is recorded, and record, identify, tune and
deploy run that loop. Another mode (extended position, velocity...) is refused.

Examples
--------
``python -m tuners.bus.calibrate --port /dev/ttyUSB0 --id 6 --out runs/bus/jaw.json``
``python -m tuners.bus.calibrate --port P --id 6 --lerobot ~/.cache/huggingface/lerobot/
calibration/robots/so101_follower/my_arm.json``
``python -m tuners.bus.calibrate --port P --id 6 --closed-ticks 1780 --open-ticks 2900``
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path

from gripper_env.hardware.bus.gripper import (
    CURRENT_POSITION_MODES,
    FACTORY_BAUD,
    MODEL_NAMES,
    POSITION_MODES,
    BusCalibrationError,
    read_servo_registers,
    select_servo,
)
from gripper_env.hardware.bus.interrupts import signals_held
from gripper_env.hardware.bus.link import BusError, BusLink
from gripper_env.io.config import validate
from gripper_env.io.files import write_json
from gripper_env.model.bus_calibration import (
    DEG_PER_TICK,
    GRIPPER_MOTOR,
    MIN_SPAN_DEG,
    JawCalibration,
    LeRobotMotor,
    ServoRegisters,
    read_lerobot_motor,
)
from gripper_env.model.bus_servo import load_bus_servo
from tuners.bus.cli import BusArgumentParser, add_servo_arguments, output_folder, run_cli
from tuners.conventions import conform

__all__ = ["main"]

#: Readings of a hand-held position; their spread must stay within this (ticks).
STEADY_TICKS = 8


def _parser() -> argparse.ArgumentParser:
    parser = BusArgumentParser(
        prog="python -m tuners.bus.calibrate",
        description="Calibrate the gripper's jaw on its bus servo (closed and open positions, "
        "and the servo's own calibration): by hand with the torque off, from given positions, "
        "or from LeRobot's calibration file. Writes the file record and deploy take as --jaw.",
    )
    add_servo_arguments(parser, keep_torque=False)
    parser.add_argument(
        "--closed-ticks",
        type=int,
        default=None,
        metavar="N",
        help="the jaw's closed position (ticks; with --open-ticks: no prompt)",
    )
    parser.add_argument(
        "--open-ticks", type=int, default=None, metavar="N", help="the jaw's open position (ticks)"
    )
    parser.add_argument(
        "--lerobot",
        type=Path,
        default=None,
        metavar="FILE",
        help="LeRobot's calibration file of the arm (~/.cache/huggingface/lerobot/calibration/"
        "robots/<robot>/<name>.json), read as data",
    )
    parser.add_argument(
        "--motor",
        default="gripper",
        help="the motor's name in --lerobot (default gripper; another motor is an arm joint, "
        "taken only with --risk-arm-joint)",
    )
    parser.add_argument(
        "--risk-arm-joint",
        action="store_true",
        help="the servo may be an arm joint, not a gripper's jaw: record, tune and deploy "
        "will drive it over its calibrated range, at their torque limits, although its "
        "motor name (--motor) or the load it carries says it is not a gripper",
    )
    parser.add_argument(
        "--closed-at",
        choices=("min", "max"),
        default=None,
        help="with --lerobot: the jaw closes at range_min or range_max (default: LeRobot's 0 %%, "
        "range_min, or range_max with drive_mode 1)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="FILE",
        help="the calibration file (default runs/bus/jaw_<family>_id<ID>.json)",
    )
    return conform(parser, "tuners.bus.calibrate")


def _check_options(args: argparse.Namespace) -> str:
    """The way the positions are given: ``"hand"``, ``"given"`` or ``"lerobot"``."""
    given = (args.closed_ticks, args.open_ticks)
    if (given[0] is None) != (given[1] is None):
        raise ValueError("--closed-ticks and --open-ticks go together")
    if given[0] is not None and abs(given[1] - given[0]) * DEG_PER_TICK < MIN_SPAN_DEG:
        raise ValueError(
            f"--closed-ticks {given[0]} and --open-ticks {given[1]} are "
            f"{abs(given[1] - given[0]) * DEG_PER_TICK:.1f} deg apart; a jaw needs at least "
            f"{MIN_SPAN_DEG:g} deg"
        )
    if args.lerobot is not None and given[0] is not None:
        raise ValueError("--lerobot and --closed-ticks/--open-ticks exclude each other")
    if args.closed_at is not None and args.lerobot is None:
        raise ValueError("--closed-at goes with --lerobot")
    if args.motor != GRIPPER_MOTOR:
        if args.lerobot is None:
            raise ValueError("--motor names a motor of --lerobot's file: give --lerobot too")
        if not args.risk_arm_joint:
            raise ValueError(
                f"--motor {args.motor}: refusing a motor that is not the gripper (record would "
                f"drive it over its whole calibrated range); calibrate --motor {GRIPPER_MOTOR}, "
                "or pass --risk-arm-joint if you mean to drive this joint"
            )
    if args.out is not None:  # before the servo is read: a folder, under a file, read-only
        from tuners.cli import check_output_file

        check_output_file(args.out, "--out")
    if args.lerobot is not None:
        return "lerobot"
    return "given" if given[0] is not None else "hand"


def _read_steady(link: BusLink, servo_id: int, what: str) -> int:
    """The present position (ticks), the median of five readings that must agree."""
    name = link.spec.role("present_position").name
    values = [link.read(servo_id, name) for _ in range(5)]
    if max(values) - min(values) > STEADY_TICKS:
        raise ValueError(
            f"the jaw moved while its {what} position was read ({min(values)} to {max(values)} "
            "ticks): hold it still and calibrate again"
        )
    return round(statistics.median(values))


def _prompt(text: str) -> None:
    print(text, flush=True)
    if sys.stdin.readline() == "":
        raise ValueError(
            "stdin closed before Enter: to calibrate without prompts pass --closed-ticks and "
            "--open-ticks (or --lerobot)"
        )


def _by_hand(link: BusLink, servo_id: int) -> tuple[int, int, str]:
    """Torque off (read back), the owner moves the jaw; the torque as found again (read back).
    Returns the closed and open positions and what the torque reads at the end."""
    torque = link.spec.role("torque_enable").name
    found = link.read(servo_id, torque)

    def restore() -> str:
        if not found:
            return "nothing was written to the servo (its torque was off)"
        with signals_held():
            try:
                link.write(servo_id, torque, found)
                back = link.read(servo_id, torque)
            except BusError as exc:
                return f"servo {servo_id}'s torque could not be turned back on ({exc})"
        return f"servo {servo_id}'s torque reads {'on' if back else 'off'} (as found: on)"

    try:
        if found:
            link.write(servo_id, torque, 0)  # read back
            print(f"servo {servo_id}'s torque is off now (read back; it was on)", flush=True)
        else:
            print(f"servo {servo_id}'s torque is off (read back)", flush=True)
        _prompt("close the jaw fully by hand, then press Enter")
        closed = _read_steady(link, servo_id, "closed")
        print(f"closed at {closed} ticks", flush=True)
        _prompt("open the jaw fully by hand, then press Enter")
        opened = _read_steady(link, servo_id, "open")
        print(f"open at {opened} ticks", flush=True)
    except BaseException as exc:
        exc.add_note(restore())
        raise
    return closed, opened, restore()


def _from_lerobot(
    args: argparse.Namespace, motor: LeRobotMotor, regs: ServoRegisters, family: str
) -> tuple[int, int]:
    """The closed and open positions of LeRobot's motor entry, once it is checked to be the
    servo as it is."""
    where = f"--lerobot {args.lerobot} ({args.motor})"
    differ = []
    if motor.homing_offset != regs.homing_offset:
        differ.append(f"homing_offset {motor.homing_offset} (the servo holds {regs.homing_offset})")
    if (motor.range_min, motor.range_max) != (regs.min_position, regs.max_position):
        differ.append(
            f"range [{motor.range_min}, {motor.range_max}] (the servo's position limits are "
            f"[{regs.min_position}, {regs.max_position}])"
        )
    if family != "sts3215" and motor.drive_mode != regs.drive_mode:
        differ.append(f"drive_mode {motor.drive_mode} (the servo holds {regs.drive_mode})")
    if differ:
        raise BusCalibrationError(
            f"{where} does not describe servo {args.id} as it is: {'; '.join(differ)}; "
            "calibrate the arm with LeRobot again, or pick the arm's own file"
        )
    closed_at = args.closed_at or ("max" if motor.drive_mode & 1 else "min")
    ends = (motor.range_min, motor.range_max)
    return (ends[0], ends[1]) if closed_at == "min" else (ends[1], ends[0])


def _run(args: argparse.Namespace) -> int:
    how = _check_options(args)
    family = load_bus_servo(args.model).family
    motor = None
    if how == "lerobot":  # read before the port is opened: bad input is refused first
        motor = read_lerobot_motor(args.lerobot, args.motor)
        if args.id is not None and motor.id != args.id:
            raise ValueError(
                f"--lerobot {args.lerobot} ({args.motor}): the motor's id is {motor.id}, not "
                f"--id {args.id}"
            )
    link = BusLink(args.port, family, args.baudrate or FACTORY_BAUD[family])
    with link:
        others = select_servo(link, args.id)
        out = args.out or Path("runs/bus") / f"jaw_{family}_id{args.id}.json"
        link.restrict(args.id)
        link.raise_on_alert = True
        regs = read_servo_registers(link, args.id)
        name = MODEL_NAMES.get(regs.model_number, family)
        print(f"servo {args.id} on {args.port}: {name}, of {len(others)} answering", flush=True)
        loop = regs.loop_mode(family)
        if loop is None:
            modes = [*POSITION_MODES[family], *CURRENT_POSITION_MODES.get(family, ())]
            raise BusCalibrationError(
                f"servo {args.id} is in operating mode {regs.operating_mode}, not position "
                f"control or current-based position control ({', '.join(map(str, modes))}): "
                "not modelled (the mode is the owner's: nothing was changed)"
            )
        if loop == "current_position":
            print(f"servo {args.id} runs current-based position control (operating mode "
                  f"{regs.operating_mode}, goal current limited by its Current_Limit "
                  f"{regs.protection.get('current_limit', '?')}): recorded, and the later "
                  "commands keep it", flush=True)  # fmt: skip
        torque_note = "nothing was written to the servo"
        if how == "hand":
            closed, opened, torque_note = _by_hand(link, args.id)
        elif motor is not None:
            closed, opened = _from_lerobot(args, motor, regs, family)
        else:
            closed, opened = args.closed_ticks, args.open_ticks
        notes = []
        if regs.limited:
            lo, hi = regs.min_position, regs.max_position
            for what, value in (("closed", closed), ("open", opened)):
                if not lo <= value <= hi:
                    if how == "given":
                        option = "--closed-ticks" if what == "closed" else "--open-ticks"
                        raise ValueError(
                            f"{option} {value} lies outside servo {args.id}'s position limits "
                            f"[{lo}, {hi}]"
                        )
                    notes.append(f"the {what} position {value} lies beyond the servo's position "
                                 f"limits [{lo}, {hi}]: taken at the limit")  # fmt: skip
            closed, opened = min(max(closed, lo), hi), min(max(opened, lo), hi)
        source = {"hand": "hand-guided", "given": "given"}.get(
            how, f"lerobot: {args.lerobot} ({args.motor})"
        )
        fields = {"family": family, "servo_id": args.id, "closed_ticks": closed,
                  "open_ticks": opened, "source": source, "servo": regs.model_dump(),
                  "motor": args.motor if how == "lerobot" else None,
                  "risk_arm_joint": args.risk_arm_joint}  # fmt: skip
        cal = validate(JawCalibration, fields, f"the jaw calibration of servo {args.id}")
    (lo_deg, hi_deg), open_deg, object_deg = cal.jaw_angles()
    output_folder(out.parent, "--out's folder")
    write_json(out, {
        "calibration": cal.model_dump(),
        "model_frame_deg": {"closed": lo_deg, "open": hi_deg, "scenarios_open": open_deg,
                            "object": object_deg},
        "written_by": "python -m tuners.bus.calibrate",
    })  # fmt: skip
    for note in notes:
        print(f"note: {note}")
    print(f"jaw of servo {args.id}: {cal.describe()}; {torque_note} -> {out}")
    print(f"next: python -m tuners.bus.record --port {args.port} --id {args.id} --model "
          f"{args.model} --jaw {out}")  # fmt: skip
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.calibrate``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

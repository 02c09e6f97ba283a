"""``python -m tuners.bus.virtual``: a virtual bus servo on a pseudo-terminal.

The servo speaks its family's protocol byte for byte (Feetech SCS/STS for the STS3215, Dynamixel
Protocol 2.0 for the XL330 and XL430) and runs the simulation core's model of its position loop
(:class:`gripper_env.hardware.bus.unit.ServoUnit`). It prints the pty path: pass it as ``--port``
to ``python -m tuners.bus.calibrate``, ``record`` and ``deploy`` (or to the vendors' own tools).
``--object DEG`` puts an object in the jaws; ``--model FILE`` runs another model than the
family's (a servo whose parameters the identification must find). ``--others 1 2 3 4 5`` puts
more servos of the family on the bus (the other joints of an arm; they only mirror their goal),
and ``--limits MIN MAX`` writes the gripper's position limits as LeRobot's calibration does, and
``--lerobot`` the registers LeRobot's configure leaves on the gripper (an SO-101's STS3215: its
overload protection at 25 %; a Koch's XL330: current-based position mode 5): the bus an owner
has, with the gripper at ``--id 6``. Stops on Ctrl-C or SIGTERM.

Examples
--------
``python -m tuners.bus.virtual --model sts3215 --link /tmp/sts3215``
``python -m tuners.bus.virtual --id 6 --others 1 2 3 4 5 --limits 1750 2950 --lerobot --link
/tmp/so101``
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Sequence

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.io.config import ConfigError
from gripper_env.model.bus_servo import load_bus_servo
from tuners.bus.cli import BusArgumentParser, servo_id
from tuners.conventions import conform

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = BusArgumentParser(
        prog="python -m tuners.bus.virtual",
        description="Run a virtual bus servo (STS3215, XL330 or XL430) on a pseudo-terminal; "
        "prints the port to pass as --port to the bus commands.",
    )
    parser.add_argument(
        "--model",
        default="sts3215",
        help="the servo: sts3215, xl330, xl430, or a model file (default sts3215)",
    )
    parser.add_argument("--id", type=servo_id, default=1, help="the servo's ID (default 1)")
    parser.add_argument(
        "--others",
        type=servo_id,
        nargs="+",
        default=[],
        metavar="ID",
        help="more servos of the family on the bus at these IDs (they mirror their goal)",
    )
    parser.add_argument(
        "--limits",
        type=int,
        nargs=2,
        default=None,
        metavar=("MIN", "MAX"),
        help="the servo's min and max position limits (ticks), written as LeRobot's "
        "calibration does (default: the factory's, the whole turn)",
    )
    parser.add_argument(
        "--lerobot",
        action="store_true",
        help="the gripper's registers as LeRobot's SO or Koch follower configures them "
        "(STS3215: P 16, I 0, D 32, Acceleration 254, Max_Torque_Limit 500, Protection_Current "
        "250, Overload_Torque 25; XL330: Return_Delay_Time 0, Operating_Mode 5, current-based "
        "position), kept in its flash as LeRobot's writes are, every servo at LeRobot's 1 Mbaud",
    )
    parser.add_argument(
        "--object",
        type=float,
        default=None,
        metavar="DEG",
        help="an object in the jaws, met at this shaft angle (deg); default none",
    )
    parser.add_argument(
        "--link",
        default=None,
        help="also make a symbolic link to the pty at this path (removed on exit)",
    )
    return conform(parser, "tuners.bus.virtual")


def _check_link(path: str | None) -> str | None:
    """``--link``'s absolute path: its folder must exist, and anything there must be a
    symbolic link (replaced), never a file."""
    if path is None:
        return None
    link = os.path.abspath(path)
    folder = os.path.dirname(link)
    if not os.path.isdir(folder):
        raise ValueError(f"--link {path}: the folder {folder} does not exist")
    if os.path.lexists(link) and not os.path.islink(link):
        raise ValueError(f"--link {path}: a file is there (only a symbolic link is replaced)")
    return link


#: The gripper's registers as LeRobot's SO-100/SO-101 follower configures them (field names):
#: every motor P 16, I 0, D 32 and Acceleration 254; the gripper's torque cut to 50 % and its
#: overload protection at 25 % (LeRobot's ``so101_follower.configure``, written with the torque
#: off, under Lock 0: saved to flash).
#: The Koch follower's gripper (an XL330, LeRobot's ``koch_follower.configure``): Return_Delay_Time
#: 0 and current-based position control (Operating_Mode 5), its Goal_Current as powered on (the
#: Current_Limit), at LeRobot's 1 Mbaud (its ``setup_motors`` writes Baud_Rate 3).
LEROBOT_GRIPPER = {
    "sts3215": {"p_coefficient": 16, "i_coefficient": 0, "d_coefficient": 32, "acceleration": 254,
                "max_torque_limit": 500, "torque_limit": 500, "protection_current": 250,
                "overload_torque": 25},
    "xl330": {"return_delay_time": 0, "operating_mode": 5, "baud_rate": 3},
}  # fmt: skip


_LEROBOT_NOTE = {"sts3215": "Overload_Torque 25 %", "xl330": "Operating_Mode 5"}


def _gripper_table(
    family: str, servo: int, limits: list[int] | None, lerobot: bool = False
) -> ControlTable:
    """The gripper servo's table, its position limits written as the host would (saved), and
    with ``lerobot`` the registers LeRobot's configure leaves (:data:`LEROBOT_GRIPPER`)."""
    table = ControlTable(family, servo)
    if lerobot:
        if family not in LEROBOT_GRIPPER:
            raise ValueError(
                f"--lerobot: LeRobot's followers have an STS3215 (SO-100/SO-101) or an XL330 "
                f"(Koch) gripper, not the {family}"
            )
        for name, value in LEROBOT_GRIPPER[family].items():
            table.store(name, value)
    if limits is not None:
        lo, hi = limits
        spec = table.spec
        for role, value in (("min_position", lo), ("max_position", hi)):
            spec.role(role).check(value)  # ValueError naming the register and its range
        if not lo < hi:
            raise ValueError(f"--limits: MIN must be below MAX, got {lo} {hi}")
        for role, value in (("min_position", lo), ("max_position", hi)):
            f = spec.role(role)
            if table.write(f.address, f.encode(value)):
                raise ValueError(f"--limits: the {family} refuses {f.name} {value}")
    return table


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m tuners.bus.virtual``; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        link = _check_link(args.link)
        model = load_bus_servo(args.model)
        if args.id in args.others or len(set(args.others)) != len(args.others):
            raise ValueError(f"--others {args.others}: each ID once, and not --id {args.id}")
        lo, hi = model.jaw.limits_deg
        if args.object is not None and not lo <= args.object <= hi:
            raise ValueError(f"--object must lie in the jaw's range [{lo:g}, {hi:g}] deg")
        gripper = _gripper_table(model.family, args.id, args.limits, args.lerobot)  # checked
        # before the physics (which compiles its kernels)
        unit = ServoUnit(model, object_deg=args.object)
        ids = sorted([gripper, *args.others], key=lambda t: t if isinstance(t, int) else t.servo_id)
        # a LeRobot bus runs at LeRobot's 1 Mbaud, every servo on it (the STS3215's factory rate)
        baud = 1_000_000 if args.lerobot else None
        bus = VirtualBus(model.family, ids=ids, physics={args.id: unit}, baudrate=baud)
    except (ConfigError, ValueError, OSError) as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    with bus:
        if link:
            try:
                if os.path.islink(link):
                    os.unlink(link)
                os.symlink(bus.path, link)
            except OSError as exc:
                parser.exit(2, f"{parser.prog}: error: --link {args.link}: {exc}\n")
        try:
            print(bus.path, flush=True)
            others = f", other servos at IDs {sorted(args.others)}" if args.others else ""
            print(
                f"virtual {model.family} ({model.name}), ID {args.id}{others}"
                + (f", position limits {args.limits}" if args.limits else "")
                + (
                    f", LeRobot's gripper registers ({_LEROBOT_NOTE[model.family]})"
                    if args.lerobot
                    else ""
                )
                + (f", object at {args.object:g} deg" if args.object is not None else "")
                + (f", linked at {link}" if link else "")
                + "; Ctrl-C to stop",
                file=sys.stderr,
                flush=True,
            )
            while not stop.wait(0.2) and bus.running:
                pass
        finally:
            if link and os.path.islink(link):
                os.unlink(link)
    return 0


if __name__ == "__main__":
    sys.exit(main())

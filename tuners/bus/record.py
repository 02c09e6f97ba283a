"""``python -m tuners.bus.record``: record a bus servo's steps at several register settings, the
records ``python -m tuners.bus.identify`` reads.

For each setting (P, I, D; default :data:`gripper_env.sysid.bus_experiments.RECORD_SETTINGS` of
the family) the servo's registers are written and read back, the torque goes on, the jaw settles
open, and the plan runs: steps of 30, 10 and 4 deg, then a creep of one tick every 20 ms (see
:mod:`gripper_env.sysid.bus_experiments`). The position is read every ``--sample-ms`` and each
record is written to ``OUT/record_p<P>_i<I>_d<D>.csv`` as soon as it is taken. Every setting is
checked stable on the family's model before anything is sent. Keep the jaws empty: the plan
moves between the open position and 30 deg closed.

Examples
--------
``python -m tuners.bus.record --port /dev/ttyUSB0 --model sts3215 --out runs/bus/sts3215``
``python -m tuners.bus.record --port P --model xl330 --settings 200,0,0 400,0,0 --out runs/x``
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from gripper_env.hardware.bus.gripper import BusGripper
from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sysid.bus_experiments import (
    BusRecorder,
    check_settings,
    record_plan,
    settings_registers,
)
from gripper_env.sysid.bus_servo import write_bus_record
from tuners.bus.cli import add_servo_arguments, run_cli

__all__ = ["main", "parse_setting"]


def parse_setting(text: str) -> tuple[int, int, int]:
    """``--settings`` item: ``P,I,D`` as three integers >= 0."""
    try:
        p, i, d = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"a setting is P,I,D (three integers), got {text!r}"
        ) from None
    if min(p, i, d) < 0 or p == 0:
        raise argparse.ArgumentTypeError(f"P must be > 0 and I, D >= 0, got {text!r}")
    return p, i, d


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.record",
        description="Record a bus servo's steps and creep at several P/I/D settings (the "
        "records identification reads). Keep the jaws empty.",
    )
    add_servo_arguments(parser)
    parser.add_argument(
        "--settings",
        nargs="+",
        type=parse_setting,
        default=None,
        metavar="P,I,D",
        help="register settings to record (default: the family's five, "
        "gripper_env.sysid.bus_experiments.RECORD_SETTINGS)",
    )
    parser.add_argument(
        "--sample-ms",
        type=float,
        default=2.0,
        help="period of the position readings (ms, default 2)",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bus"), help="records folder (default runs/bus)"
    )
    return parser


def _run(args: argparse.Namespace) -> int:
    model = load_bus_servo(args.model)
    registers = settings_registers(model, args.settings)
    check_settings(model, registers)  # before anything is sent
    plan = record_plan(model)
    args.out.mkdir(parents=True, exist_ok=True)
    with BusGripper(args.port, model, args.id, baudrate=args.baudrate) as jaw:
        recorder = BusRecorder(jaw, sample_s=args.sample_ms / 1e3)
        for k, regs in enumerate(registers, start=1):
            rec = recorder.record(regs, plan)
            path = args.out / f"record_p{regs.p}_i{regs.i}_d{regs.d}.csv"
            write_bus_record(path, rec)
            dt = (rec.t_s[-1] - rec.t_s[0]) / max(rec.t_s.size - 1, 1)
            print(
                f"[{k}/{len(registers)}] {regs.label()}: {rec.t_s.size} readings "
                f"(every {dt * 1e3:.2f} ms), {rec.goal_times_s.size} goals, "
                f"{recorder.lost} replies lost and {recorder.slow} slow readings dropped so far "
                f"-> {path}",
                flush=True,
            )
        recorder.settle(model.jaw.open_deg, 0.2)
    print(f"recorded {len(registers)} settings on {args.port}; next: python -m "
          f"tuners.bus.identify {args.out}/record_*.csv --model {args.model}")  # fmt: skip
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.record``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

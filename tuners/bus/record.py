"""``python -m tuners.bus.record``: record a bus servo's steps at several register settings, the
records ``python -m tuners.bus.identify`` reads.

Before anything is written: every setting is checked stable on the family's model, the plan is
checked to lie inside the jaw calibration's goal range (``--jaw``, from ``python -m
tuners.bus.calibrate``), the servo of ``--id`` is found on the bus (a broadcast ping lists the
others; nothing is sent to them), and its calibration registers are read and compared with the
jaw file's. A **load probe** comes first, with the stiffest setting's registers: the torque on
where the servo holds, the goal creeping 3 deg (or three dead bands) towards the middle of
the calibrated range and back
(:meth:`gripper_env.sysid.bus_experiments.BusRecorder.probe_load`); a steady load above 3 % of
full drive, which a gripper's jaw does not carry, marks an arm joint under gravity and stops
the command (exit 2, the servo restored) unless the calibration says ``--risk-arm-joint``. Then,
for each setting (P, I, D; default
:data:`gripper_env.sysid.bus_experiments.RECORD_SETTINGS` of the family; the torque limit at
most what the servo was found with and its maximum torque limit), the registers are written (on
an STS3215 with ``Lock`` = 1: nothing is saved to its flash) and read back, the torque goes on,
the jaw settles open, and the plan runs: steps of 30, 10 and 4 deg closing from the open
position, then a creep of one tick every 20 ms (see :mod:`gripper_env.sysid.bus_experiments`).
The position is read every ``--sample-ms`` and each record (with the jaw calibration) is written
to ``OUT/record_p<P>_i<I>_d<D>.csv`` as soon as it is taken. At the end, on an error, on Ctrl-C
or SIGTERM, every register written is restored and read back, the torque as it was found
(unless ``--keep-torque``). Keep the jaws empty. On an XL330 that the calibration found in
current-based position control (operating mode 5, the Koch gripper's), the default settings are
:data:`gripper_env.sysid.bus_experiments.CURRENT_RECORD_SETTINGS` (D in each) and every record
runs at the goal current the servo holds, within its ``Current_Limit``.

Examples
--------
``python -m tuners.bus.record --port /dev/ttyUSB0 --id 6 --jaw runs/bus/jaw.json --out runs/bus``
``python -m tuners.bus.record --port P --id 1 --model xl330 --jaw J --settings 200,0,0 400,0,0``
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from tuners.bus.cli import (
    EXIT_FAILURE,
    BusArgumentParser,
    add_servo_arguments,
    load_jaw,
    open_gripper,
    output_folder,
    run_cli,
)
from tuners.conventions import conform

if TYPE_CHECKING:  # the library is imported after parsing: --help answers before it loads
    from gripper_env.hardware.bus.gripper import BusGripper

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
    parser = BusArgumentParser(
        prog="python -m tuners.bus.record",
        description="Record a bus servo's steps and creep at several P/I/D settings (the "
        "records identification reads), inside its calibrated jaw; the servo is left as "
        "found. Keep the jaws empty.",
    )
    add_servo_arguments(parser)
    parser.add_argument(
        "--jaw",
        default=None,
        metavar="FILE",
        help="the jaw calibration (python -m tuners.bus.calibrate); required unless --model "
        "is an identified model file that carries one",
    )
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
    parser.add_argument(
        "--force",
        action="store_true",
        help="exit 0 even if a record has a clipped step or more than 10 %% of its readings "
        "lost (python -m tuners.bus.identify then needs --force too)",
    )
    return conform(parser, "tuners.bus.record")


def _run(args: argparse.Namespace) -> int:
    if not 0.0 < args.sample_ms <= 100.0:
        raise ValueError(f"--sample-ms must be in (0, 100] ms, got {args.sample_ms}")
    # the library after parsing: --help and a usage error answer before it loads
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.sysid.bus_experiments import (
        BusRecorder,
        check_load,
        check_plan,
        check_record,
        check_settings,
        record_plan,
        settings_registers,
    )
    from gripper_env.sysid.bus_servo import write_bus_record

    model = load_bus_servo(args.model)
    calibration = load_jaw(args.jaw, model, args.id)
    # the loop the servo was found in (calibrate recorded its operating mode): mode 5, current-
    # based position control, records in that mode
    model = model.calibrated(calibration)
    registers = settings_registers(model, args.settings)
    check_settings(model, registers)  # before anything is sent
    plan = record_plan(model)
    check_plan(plan, calibration.goal_range_deg(), "record's plan (steps of 30, 10, 4 deg)")
    out = output_folder(args.out)
    with open_gripper(args, model, calibration) as jaw:
        limit = min(jaw.found["torque_limit"], jaw.servo_registers.max_torque_limit)
        capped = [r.model_copy(update={"torque_limit": min(r.torque_limit, limit)})
                  for r in registers]  # fmt: skip
        if any(c != r for c, r in zip(capped, registers, strict=True)):
            print(f"note: torque limit held at {limit}, the servo's own (as found, within its "
                  "maximum)", flush=True)  # fmt: skip
        if jaw.model.current_mode:
            current = _goal_current(jaw)
            capped = [r.model_copy(update={"goal_current": current}) for r in capped]
            print(f"note: current-based position control (operating mode "
                  f"{jaw.servo_registers.operating_mode}): recorded at goal current {current}, "
                  "the servo's own (as found, within its Current_Limit)", flush=True)  # fmt: skip
        for regs in capped:
            jaw.register_values(regs)  # every setting checked before the first is written
        recorder = BusRecorder(jaw, sample_s=args.sample_ms / 1e3)
        # before the plan's large steps: a small creep where the servo holds, both ways; a
        # steady load (gravity on an arm joint) stops the command here
        probe = recorder.probe_load(max(capped, key=lambda r: r.p))  # the stiffest setting
        print(f"load probe: {probe.describe(model.physics.stall_torque_nm)}", flush=True)
        warning = check_load(probe, model, calibration.risk_arm_joint)
        if warning:
            print(f"warning: {warning}", file=sys.stderr, flush=True)
        problems: list[str] = []
        for k, regs in enumerate(capped, start=1):
            rec = recorder.record(regs, plan)
            path = out / f"record_p{regs.p}_i{regs.i}_d{regs.d}.csv"
            write_bus_record(path, rec)
            problems += check_record(rec, str(path), model)
            dt = (rec.t_s[-1] - rec.t_s[0]) / max(rec.t_s.size - 1, 1)
            print(
                f"[{k}/{len(capped)}] {rec.registers.label()}: {rec.t_s.size} readings "
                f"(every {dt * 1e3:.2f} ms; {rec.stats['lost']} lost, {rec.stats['slow']} slow "
                f"ones kept with their round trips), {rec.goal_times_s.size} goals -> {path}",
                flush=True,
            )
        recorder.settle(model.jaw.open_deg, 0.2)
    assert jaw.restored is not None
    print(jaw.restored.describe())
    print(f"recorded {len(capped)} settings on {args.port} ({jaw.link.retried} replies lost and "
          f"sent again)")  # fmt: skip
    if problems and not args.force:
        for text in problems:
            print(f"{_parser().prog}: error: {text}", file=sys.stderr)
        print(f"{_parser().prog}: error: the records are written but not fit to identify "
              "from: record again (the jaws empty, a quieter host), or pass --force here and "
              "to identify", file=sys.stderr, flush=True)  # fmt: skip
        return EXIT_FAILURE
    for text in problems:
        print(f"warning (--force): {text}", file=sys.stderr)
    print(f"next: python -m tuners.bus.identify {out}/record_*.csv --model {args.model}"
          + (" --force" if problems else ""))  # fmt: skip
    return 0


def _goal_current(jaw: BusGripper) -> int:
    """The goal current a record in current-based position control runs at: the servo's as
    found, within its ``Current_Limit`` (ValueError, nothing written, when it is 0: the servo
    would hold no torque)."""
    found = abs(jaw.found["goal_current"])
    limit = jaw.servo_registers.protection.get("current_limit")
    current = found if limit is None else min(found, limit)
    if current <= 0:
        raise ValueError(
            f"servo {jaw.servo_id} runs current-based position control with goal current "
            f"{found} (Current_Limit {limit}): it holds no torque, nothing to record (set its "
            "Goal_Current, or its mode, as you use it)"
        )
    return current


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.record``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

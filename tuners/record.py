"""Record an open-loop identification experiment on the gripper.

``python -m tuners.record --port P --profile slope60 [--output LOG.csv]``

Streams the profile (``step``, ``slope60``, ``slope40``, ``slope20``, ``ramp3`` or a CSV file)
to the board in open loop (the desired angle is the servo command, as in the paper's tests)
and logs ``t_s, desired_deg, actual_deg`` at 1 kHz, the columns
``python -m gripper_env.sysid LOG.csv`` reads. The log is written as it goes (flushed every
20 ms) under ``LOG.partial.csv`` and renamed to ``LOG.csv`` when the profile completes; a run
that fails keeps its partial log. ``desired_deg`` is the command the board applied (the host's
setpoint as the board saw it), ``actual_deg`` the potentiometer through the calibration.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gripper_env.hardware.calibration import load_calibration
from gripper_env.hardware.device import GripperDevice, TelemetryBlock
from gripper_env.hardware.experiment import CsvLog, run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.references import PROFILES, load_reference
from tuners.hardware_common import add_device_arguments, run_cli

__all__ = ["RECORD_COLUMNS", "main"]

RECORD_COLUMNS = ("t_s", "desired_deg", "actual_deg")


def record_rows(block: TelemetryBlock, t0_us: int) -> np.ndarray:
    """CSV rows ``t_s, desired_deg, actual_deg`` of a telemetry block."""
    return np.column_stack([(block.t_us - t0_us) / 1e6, block.reference_deg, block.position_deg])


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.record",
        description="Run an open-loop experiment on the board and save the CSV that "
        "identification reads (t_s, desired_deg, actual_deg).",
    )
    add_device_arguments(parser)
    parser.add_argument(
        "--profile",
        default="slope60",
        help=f"reference profile: {', '.join(PROFILES)}, or a CSV file with t_s and "
        "desired_deg (default: slope60)",
    )
    parser.add_argument(
        "--output",
        default=None,
        metavar="FILE",
        help="CSV log to write (default: results/hardware/record_PROFILE.csv)",
    )
    return parser


def _run(args: argparse.Namespace) -> int:
    reference = load_reference(args.profile)
    calibration = load_calibration(args.calibration)
    output = Path(args.output or f"results/hardware/record_{reference.name}.csv")
    log = CsvLog(output, RECORD_COLUMNS, record_rows)
    with GripperDevice(
        args.port, calibration=calibration, boot_wait_s=args.boot_wait, timeout_s=args.timeout
    ) as device:
        device.configure()
        try:
            rec = run_profile(device, reference, Mode.OPEN_LOOP, log=log)
        except BaseException:
            print(f"{log.rows} samples so far kept in {log.partial}", file=sys.stderr)
            raise
    print(
        f"recorded {reference.name}: {len(rec.samples)} samples over "
        f"{reference.duration_s:g} s, {rec.frames_lost} frames lost -> {rec.extra['log']}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.record``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

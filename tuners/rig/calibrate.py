"""Two-point ADC-to-angle calibration of the gripper's potentiometer.

``python -m tuners.rig.calibrate --port P [--output FILE]``

Recipe: open the board, drive the jaw open loop to 92 deg, then to 21 deg (closed), then back
to 92 deg, let it settle at each end (``--settle``) and average the ADC readings over
``--average`` seconds. The counts at 21 and 92 deg, the date, the port and the board's device
id are written to the board's own calibration file (default
``~/.config/gripper_env/calibrations/<device id>.json``, one per board: a virtual board's never
replaces a real one's; ``--output`` or ``$GRIPPER_CALIBRATION`` name another file, refused if
it holds another board's calibration), which ``tuners.rig.record``, ``tuners.rig.deploy`` and
the hardware environment read. The jaw must be free to reach both ends (nothing between the
jaws).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.hardware.host.calibration import (
    Calibration,
    CalibrationError,
    calibration_path_for,
    calibrations_dir,
    check_device,
    load_calibration,
    save_calibration,
)
from gripper_env.hardware.protocol import Mode
from tuners.conventions import conform
from tuners.rig.cli import add_device_arguments, positive_float, run_cli

if TYPE_CHECKING:  # imported where it is used: --help answers before numba loads
    from gripper_env.hardware.host.device import GripperDevice

__all__ = ["main", "measure_counts"]


def measure_counts(
    device: GripperDevice, angle_deg: float, settle_s: float, average_s: float
) -> tuple[float, float, int]:
    """Command ``angle_deg`` open loop, wait ``settle_s``, average the ADC over ``average_s``.

    Returns
    -------
    mean, std : float
        ADC counts.
    n : int
        Samples averaged.
    """
    device.set_setpoint(angle_deg, confirm=True)  # one command, not a stream: it must arrive
    device.wait_telemetry(settle_s)
    block = device.wait_telemetry(average_s)
    active = block.adc[block.mode == Mode.OPEN_LOOP]
    if len(active) < 2:
        raise ValueError(
            f"the board left open loop while calibrating at {angle_deg:g} deg "
            f"(got {len(active)} samples)"
        )
    return float(np.mean(active)), float(np.std(active, ddof=1)), len(active)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rig.calibrate",
        description="Measure the ADC counts with the jaw at 21 and 92 deg and save them.",
    )
    add_device_arguments(parser, calibration=False)
    parser.add_argument(
        "--output",
        default=None,
        metavar="FILE",
        help="calibration file to write, refused if it holds another board's (default: "
        f"$GRIPPER_CALIBRATION, else the board's own in {calibrations_dir()}, named by its "
        "device id)",
    )
    parser.add_argument(
        "--settle",
        type=positive_float,
        default=1.5,
        metavar="S",
        help="seconds to let the jaw settle at each end before reading (default: 1.5)",
    )
    parser.add_argument(
        "--average",
        type=positive_float,
        default=0.5,
        metavar="S",
        help="seconds of readings averaged at each end (default: 0.5)",
    )
    return conform(parser, "tuners.rig.calibrate")


def _run(args: argparse.Namespace) -> int:
    if args.average <= 0.01:
        raise ValueError("--average must be more than 0.01 s")
    from gripper_env.hardware.host.device import GripperDevice
    from tuners.rig.cli import given_calibration

    args.calibration = args.output
    named, option = given_calibration(args)
    with GripperDevice(args.port, boot_wait_s=args.boot_wait, timeout_s=args.timeout) as device:
        device_id = device.info.device_id if device.info else None
        path = named if named is not None else calibration_path_for(device_id, args.port)
        if named is not None and named.exists():  # before the jaw moves
            try:
                check_device(load_calibration(named, option), device_id, args.port,
                             f"{option.replace('--calibration', '--output')} {named}")  # fmt: skip
            except CalibrationError as exc:
                raise CalibrationError(f"{exc}; not replaced (give another --output)") from None
        device.set_setpoint(92.0)
        device.set_mode(Mode.OPEN_LOOP)
        device.wait_telemetry(args.settle)  # start from the open end
        lo, lo_std, n_lo = measure_counts(device, 21.0, args.settle, args.average)
        hi, hi_std, n_hi = measure_counts(device, 92.0, args.settle, args.average)
        device.set_mode(Mode.IDLE)
        info = device.info
    cal = Calibration.measured(
        lo,
        hi,
        port=args.port,
        device_id=info.device_id if info else None,
        samples=[n_lo, n_hi],
        noise_counts=[round(lo_std, 3), round(hi_std, 3)],
    )
    path = save_calibration(cal, path)
    print(
        f"calibration: {lo:.2f} counts at 21 deg, {hi:.2f} counts at 92 deg "
        f"({abs(cal.deg_per_count):.3f} deg per count) -> {path}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rig.calibrate``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

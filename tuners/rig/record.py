"""Record an open-loop identification experiment on the gripper.

``python -m tuners.rig.record --port P --profile slope60 [--output LOG.csv]``

Streams the profile (``step``, ``slope60``, ``slope40``, ``slope20``, ``ramp3`` or a CSV file)
to the board in open loop (the desired angle is the servo command, as in the paper's tests) and
logs ``t_s, desired_deg, actual_deg`` at 1 kHz, the columns ``python -m tuners.sysid LOG.csv``
reads. The log is written as it goes (flushed every 20 ms) under ``LOG.partial.csv`` and renamed
to ``LOG.csv`` when the profile completes; a run that fails keeps its partial log. A run that
completes with samples missing (telemetry frames lost on the link: identification refuses a
record with gaps) is recorded again, up to ``--attempts`` runs in all; each gapped log is kept
beside it as ``LOG.attemptK.csv``, and after the last the command fails naming the gaps.
``desired_deg`` is the command the board applied (the host's setpoint as the board saw it),
``actual_deg`` the potentiometer through the calibration. The recording is the library's
(:class:`gripper_env.sysid.experiments.DeviceRecorder`, which ``python -m tuners.sysid
experiments --port P`` runs once per Table-1 experiment).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from gripper_env.io.files import path_in
from gripper_env.model.references import PROFILES, load_reference
from tuners.cli import DEFAULT_OUT, check_output_file
from tuners.conventions import command_parser
from tuners.rig.cli import add_device_arguments, given_calibration, run_cli

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = command_parser(
        "tuners.rig.record",
        "Run an open-loop experiment on the board and save the CSV that identification reads "
        "(t_s, desired_deg, actual_deg).",
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
        help="CSV log to write (default: runs/hardware/record_PROFILE.csv)",
    )
    parser.add_argument(
        "--attempts",
        type=int,
        default=3,
        metavar="N",
        help="runs of the profile at most, while a completed run has samples missing (frames "
        "lost on the link); each gapped log is kept as FILE.attemptK.csv (default: 3)",
    )
    return parser


def every_s(period_s: float, duration_s: float) -> Callable[[float], None]:
    """A progress callback that prints ``  40 % (24 of 60 s)`` on stderr at most every
    ``period_s`` of wall time."""
    last = [time.monotonic()]

    def show(fraction: float) -> None:
        now = time.monotonic()
        if now - last[0] >= period_s:
            last[0] = now
            print(f"  {100 * fraction:3.0f} % ({fraction * duration_s:.0f} of {duration_s:g} s)",
                  file=sys.stderr, flush=True)  # fmt: skip

    return show


def _run(args: argparse.Namespace) -> int:
    if args.attempts < 1:
        raise ValueError(f"--attempts must be at least 1, got {args.attempts}")  # before the port
    reference = load_reference(args.profile)
    default = path_in(DEFAULT_OUT / "hardware", f"record_{reference.name}.csv", what="profile")
    output = Path(args.output) if args.output else default
    check_output_file(output, "--output", ".csv")  # before the board moves
    from gripper_env.hardware.host.calibration import load_calibration

    # a file given is read before the port opens (and checked against the board after the
    # handshake); without one, the board's own calibration is found by its device id
    path, option = given_calibration(args)
    calibration = None if path is None else load_calibration(path, option)
    print(f"recording {reference.name} ({reference.duration_s:g} s of device time) on "
          f"{args.port}...", file=sys.stderr, flush=True)  # fmt: skip
    from gripper_env.sysid.experiments import DeviceRecorder  # after parsing: --help is light

    recorder = DeviceRecorder(args.port, calibration, args.boot_wait, args.timeout,
                              calibration_source=f"{option} {path}",
                              fraction=every_s(10.0, reference.duration_s),
                              attempts=args.attempts,
                              warn=lambda m: print(m, file=sys.stderr, flush=True))  # fmt: skip
    rec = recorder.record(reference, output)
    print(
        f"recorded {reference.name}: {len(rec.samples)} samples over "
        f"{reference.duration_s:g} s, {rec.frames_lost} frames lost -> {rec.extra['log']}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rig.record``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

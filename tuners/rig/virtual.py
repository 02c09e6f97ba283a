"""The command line of the boards on a pseudo-terminal: ``python -m tuners.rig.virtual``
(the firmware's Python twin) and ``python -m tuners.rig.virtual --emulated`` (the compiled image
under simavr). Both print the pty path to pass as ``--port`` to the host tools.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Sequence

from gripper_env.hardware.emulator.build import ensure_built
from gripper_env.hardware.virtual import VirtualDevice
from tuners.conventions import conform

__all__ = ["board_parser", "main", "parse_speed"]


def parse_speed(text: str) -> float:
    """``--speed`` value: a factor >= 0, or ``max`` (same as 0: as fast as possible)."""
    if text.strip().lower() == "max":
        return 0.0
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"speed must be a number >= 0 or 'max', got {text!r}"
        ) from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"speed must be a finite number >= 0 or 'max', got {text}")
    return value


def board_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m tuners.rig.virtual``."""
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rig.virtual",
        description="Run a gripper board on a pseudo-terminal over the simulated actual gripper: "
        "the firmware's Python twin (protocol, modes, watchdog), or with --emulated the compiled "
        "Mega 2560 image under simavr (its own servo pulses drive the rig, its ADC reads it; the "
        "image and the harness are built with the project's scripts when missing). Prints the "
        "pty path; pass it as --port to the host tools (with --boot-wait 0: the board boots at "
        "once). Stops on Ctrl-C or SIGTERM.",
    )
    parser.add_argument("--plant", default="test2", help="plant name or YAML file (default: test2)")
    parser.add_argument(
        "--disturbance",
        default="actual",
        help="actual-gripper preset name or YAML file (default: actual)",
    )
    parser.add_argument(
        "--speed",
        type=parse_speed,
        default=1.0,
        help="device time per wall-clock time: 1 = real time, 2 = twice as fast, "
        "0 or 'max' = as fast as possible, paced by an active host (default: 1)",
    )
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed (default: 0)")
    parser.add_argument(
        "--y0",
        type=float,
        default=92.0,
        help="jaw angle at power-on, deg (default: 92, open)",
    )
    parser.add_argument(
        "--link",
        default=None,
        help="also make a symbolic link to the pty at this path (removed on exit)",
    )
    parser.add_argument(
        "--emulated",
        action="store_true",
        help="run the compiled firmware image under simavr instead of the Python twin",
    )
    parser.add_argument(
        "--image",
        default=None,
        metavar="ELF",
        help="the firmware image to run under simavr (implies --emulated; default with "
        "--emulated: firmware/build-mega/gripper.elf, built by firmware/build.sh when missing)",
    )
    parser.add_argument(
        "--rebuild",
        action="store_true",
        help="with --emulated: rebuild the default image and the harness before starting",
    )
    return conform(parser, "tuners.rig.virtual")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m tuners.rig.virtual`` with the arguments ``argv``; return the exit status."""
    parser = board_parser()
    args = parser.parse_args(argv)
    emulated = args.emulated or args.image is not None
    try:
        if not 0.0 <= args.y0 <= 180.0:
            raise ValueError(f"--y0 must be an angle in [0, 180] deg, got {args.y0}")
        image = args.image
        if emulated:
            image, _harness = ensure_built(args.image, rebuild=args.rebuild)
        device = VirtualDevice(
            args.plant, args.disturbance, speed=args.speed, seed=args.seed, y0_deg=args.y0,
            image=image,
        )  # fmt: skip
    except (ValueError, OSError, RuntimeError) as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    device.start()
    link = None
    try:
        if args.link:
            link = os.path.abspath(args.link)
            if os.path.islink(link):
                os.unlink(link)
            os.symlink(device.path, link)
        speed = "max" if args.speed == 0 else f"{args.speed:g}x"
        board = f"firmware image {image}" if image else "the firmware's Python twin"
        print(device.path, flush=True)
        print(
            f"virtual gripper ({board}): plant {args.plant}, disturbance {args.disturbance}, "
            f"speed {speed}" + (f", linked at {link}" if link else "") + "; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        while not stop.wait(0.2):
            if not device.running:
                break
    except OSError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        device.stop()
        if link and os.path.islink(link):
            os.unlink(link)
    if device.error is not None:
        print(f"{parser.prog}: error: the board stopped: {device.error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

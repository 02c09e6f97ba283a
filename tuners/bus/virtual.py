"""``python -m tuners.bus.virtual``: a virtual bus servo on a pseudo-terminal.

The servo speaks its family's protocol byte for byte (Feetech SCS/STS for the STS3215, Dynamixel
Protocol 2.0 for the XL330 and XL430) and runs the simulation core's model of its position loop
(:class:`gripper_env.hardware.bus.unit.ServoUnit`). It prints the pty path: pass it as ``--port``
to ``python -m tuners.bus.record`` and ``python -m tuners.bus.deploy`` (or to the vendors' own
tools). ``--object DEG`` puts an object in the jaws; ``--truth FILE`` runs another model than
the family's (a servo whose parameters the identification must find). Stops on Ctrl-C or
SIGTERM.

Examples
--------
``python -m tuners.bus.virtual --model sts3215 --link /tmp/sts3215``
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Sequence

from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.io.config import ConfigError
from gripper_env.model.bus_servo import load_bus_servo

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.virtual",
        description="Run a virtual bus servo (STS3215, XL330 or XL430) on a pseudo-terminal; "
        "prints the port to pass as --port to the bus commands.",
    )
    parser.add_argument(
        "--model",
        default="sts3215",
        help="the servo: sts3215, xl330, xl430, or a model file (default sts3215)",
    )
    parser.add_argument("--id", type=int, default=1, help="the servo's ID (default 1)")
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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m tuners.bus.virtual``; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        model = load_bus_servo(args.model)
        if not 0 <= args.id <= 252:
            raise ValueError(f"--id must be 0..252, got {args.id}")
        lo, hi = model.jaw.limits_deg
        if args.object is not None and not lo <= args.object <= hi:
            raise ValueError(f"--object must lie in the jaw's range [{lo:g}, {hi:g}] deg")
        unit = ServoUnit(model, object_deg=args.object)
        bus = VirtualBus(model.family, ids=(args.id,), physics=unit)
    except (ConfigError, ValueError, OSError) as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    link = None
    with bus:
        if args.link:
            link = os.path.abspath(args.link)
            if os.path.islink(link):
                os.unlink(link)
            os.symlink(bus.path, link)
        try:
            print(bus.path, flush=True)
            print(
                f"virtual {model.family} ({model.name}), ID {args.id}"
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

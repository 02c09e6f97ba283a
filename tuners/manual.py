"""Evaluate given gains: the paper's, typed ones, or a gains file.

Usage::

    python -m tuners.manual --plant test2 --gains paper-tuned
    python -m tuners.manual --plant test2 --gains paper-hw-tuned      # uses e = y - r, says so
    python -m tuners.manual --plant test2 --gains 1,9,-0.001[,100] --save-trajectory run.csv
    python -m tuners.manual --plant test3 --gains results/test2/optuna.json

Writes ``<out>/<plant>/manual-<preset>.json`` (or ``manual.json`` for typed gains or a file) and
the response plot beside it, and prints the metrics table.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gripper_env import paper
from tuners import cli

if TYPE_CHECKING:
    from gripper_env.model.pid import PIDGains
    from tuners.interface import Budget, Tuned

__all__ = ["PRESETS", "ManualGains", "ManualTuner", "main", "paper_gains", "parse_gains"]


@dataclass(frozen=True)
class ManualGains:
    """Gains to evaluate, their error sign convention, and where they came from."""

    gains: PIDGains
    sign: int
    label: str
    note: str = ""


_HW_NOTE = "note: the paper's hardware gains are unstable with e = r - y; using e = y - r (sign -1)"

#: The paper's Table 3 (:data:`gripper_env.paper.PID_GAINS`) by preset name, with the error sign
#: each is stable with: the hardware gains are unstable with e = r - y and stable with e = y - r.
PRESETS: dict[str, tuple[str, int]] = {
    "paper-untuned": ("untuned_tf", 1),
    "paper-tuned": ("tuned_tf", 1),
    "paper-hw-untuned": ("untuned_hw", -1),
    "paper-hw-tuned": ("tuned_hw", -1),
}


@functools.cache
def paper_gains() -> dict[str, ManualGains]:
    from gripper_env.model.pid import PIDGains

    return {
        name: ManualGains(PIDGains(*paper.PID_GAINS[key]), sign, name, _HW_NOTE if sign < 0 else "")
        for name, (key, sign) in PRESETS.items()
    }


def __getattr__(name: str) -> Any:
    if name == "PAPER_GAINS":  # kept for callers: paper_gains(), built on first use (numba)
        return paper_gains()
    raise AttributeError(f"module 'tuners.manual' has no attribute {name!r}")


def parse_gains(text: str) -> ManualGains:
    """A preset name, ``P,I,D[,N]``, or a gains file path.

    Raises
    ------
    ValueError
        Not a preset, not 3 or 4 finite numbers in range (:data:`gripper_env.model.pid.MAX_GAIN`),
        and not a ``.json`` file.
    """
    from gripper_env.model.gains_file import load_gains_file
    from gripper_env.model.pid import PIDGains

    if text in PRESETS:
        return paper_gains()[text]
    if text.endswith(".json") or Path(text).is_file():
        f = load_gains_file(text)
        return ManualGains(f.gains, f.options.sign, "", f"gains from {text} ({f.tuner}, {f.plant})")
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (3, 4) or not all(math.isfinite(v) for v in values):
        raise ValueError(
            f"--gains must be a preset ({', '.join(PRESETS)}), 3 or 4 finite numbers "
            f"'P,I,D[,N]', or a gains .json file; got {text!r}"
        )
    try:
        return ManualGains(PIDGains(*values), 1, "")
    except ValueError as exc:
        raise ValueError(f"--gains {text!r}: {exc}") from None


class ManualTuner:
    """The paper's gains as a benchmark row (:class:`tuners.interface.Tuner`)."""

    kind = "manual"
    plants: tuple[str, ...] = ()

    def __init__(self, preset: str) -> None:
        if preset not in PRESETS:
            raise ValueError(f"unknown manual preset {preset!r}; choose one of "
                             f"{', '.join(PRESETS)}")  # fmt: skip
        self.chosen = paper_gains()[preset]
        self.name = f"manual-{preset}"

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        from tuners.interface import Tuned

        c = self.chosen
        return Tuned(c.gains, c.sign, {"preset": c.label}, label=c.label)


def build_parser():
    parser = cli.base_parser("tuners.manual", "Evaluate given PID gains.")
    parser.add_argument(
        "--gains",
        required=True,
        help=f"a preset ({', '.join(PRESETS)}), 'P,I,D[,N]', or a gains .json file",
    )
    parser.add_argument(
        "--sign",
        type=int,
        choices=(1, -1),
        default=None,
        help="error sign: 1 for e = r - y, -1 for e = y - r (default: the preset's or file's, "
        "else 1)",
    )
    parser.add_argument(
        "--save-trajectory",
        type=Path,
        default=None,
        metavar="FILE.csv",
        help="write the actual-model run of the first held-out seed as CSV: t_s, "
        "reference_deg, command_deg, position_deg (measured)",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m tuners.manual`` and ``gripper-manual``."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    # check every input before anything is written
    chosen = parse_gains(args.gains)
    cli.check_output_file(args.save_trajectory, "--save-trajectory", ".csv")  # before the work
    inputs = cli.resolve(args)
    sign = chosen.sign if args.sign is None else args.sign
    start = time.perf_counter()
    notes = [chosen.note] if chosen.note and not args.json else []
    if chosen.note and args.json:
        print(chosen.note, file=sys.stderr)
    stem = f"manual-{chosen.label}" if chosen.label else "manual"
    _, ev = cli.publish(
        args,
        inputs,
        tuner=stem,
        gains=chosen.gains,
        sign=sign,
        label=chosen.label or args.gains,
        tuning={"source": args.gains, "note": chosen.note},
        wall_time_s=time.perf_counter() - start,
        notes=notes,
    )
    if args.save_trajectory is not None:
        ev.actual_trajectory.to_csv(args.save_trajectory)
        if not args.json:
            print(f"wrote {args.save_trajectory} (actual model, seed {ev.seeds[0]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

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

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from gripper_env import paper
from gripper_env.model.gains_file import load_gains_file
from gripper_env.model.pid import PIDGains
from tuners import cli
from tuners.interface import Budget, Tuned

__all__ = ["PAPER_GAINS", "ManualGains", "ManualTuner", "main", "parse_gains"]


@dataclass(frozen=True)
class ManualGains:
    """Gains to evaluate, their error sign convention, and where they came from."""

    gains: PIDGains
    sign: int
    label: str
    note: str = ""


_HW_NOTE = "note: the paper's hardware gains are unstable with e = r - y; using e = y - r (sign -1)"

#: The paper's Table 3 (:data:`gripper_env.paper.PID_GAINS`). The hardware gains are unstable
#: with e = r - y and stable with e = y - r.
PAPER_GAINS: dict[str, ManualGains] = {
    "paper-untuned": ManualGains(PIDGains(*paper.PID_GAINS["untuned_tf"]), 1, "paper-untuned"),
    "paper-tuned": ManualGains(PIDGains(*paper.PID_GAINS["tuned_tf"]), 1, "paper-tuned"),
    "paper-hw-untuned": ManualGains(
        PIDGains(*paper.PID_GAINS["untuned_hw"]), -1, "paper-hw-untuned", _HW_NOTE
    ),
    "paper-hw-tuned": ManualGains(
        PIDGains(*paper.PID_GAINS["tuned_hw"]), -1, "paper-hw-tuned", _HW_NOTE
    ),
}


def parse_gains(text: str) -> ManualGains:
    """A preset name, ``P,I,D[,N]``, or a gains file path.

    Raises
    ------
    ValueError
        Not a preset, not 3 or 4 finite numbers in range (:data:`gripper_env.model.pid.MAX_GAIN`),
        and not a ``.json`` file.
    """
    if text in PAPER_GAINS:
        return PAPER_GAINS[text]
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
            f"--gains must be a preset ({', '.join(PAPER_GAINS)}), 3 or 4 finite numbers "
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
        if preset not in PAPER_GAINS:
            raise ValueError(f"unknown manual preset {preset!r}; choose one of "
                             f"{', '.join(PAPER_GAINS)}")  # fmt: skip
        self.chosen = PAPER_GAINS[preset]
        self.name = f"manual-{preset}"

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        c = self.chosen
        return Tuned(c.gains, c.sign, {"preset": c.label}, label=c.label)


def build_parser():
    parser = cli.base_parser("python -m tuners.manual", "Evaluate given PID gains.")
    parser.add_argument(
        "--gains",
        required=True,
        help=f"a preset ({', '.join(PAPER_GAINS)}), 'P,I,D[,N]', or a gains .json file",
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
    if args.save_trajectory is not None and args.save_trajectory.suffix != ".csv":
        raise ValueError(f"--save-trajectory must name a .csv file, got {args.save_trajectory}")
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

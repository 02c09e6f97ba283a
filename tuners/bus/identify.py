"""``python -m tuners.bus.identify``: identify a bus servo's loop from its records.

Reads the records of ``python -m tuners.bus.record`` (two or more P settings), fits the servo's
model (:func:`gripper_env.sysid.bus_servo.identify_bus_servo`: the register-to-duty scales, the
motor's time constant and speed, Coulomb and static friction, the goal's and the loop's delays),
prints each value with its standard error and 95 % range, and writes ``OUT/NAME_model.json``
(the model that ``python -m tuners.bus.tune --model`` and ``python -m tuners.bus.virtual
--model`` take, with its uncertainties, which the tuner's robustness corners use) and
``OUT/NAME_fit.png`` (each record against the model).

Examples
--------
``python -m tuners.bus.identify runs/bus/sts3215/record_*.csv --model sts3215 --name my-sts3215``
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gripper_env.io.files import safe_name, save_figure, write_json
from tuners.bus.cli import EXIT_FAILURE, run_cli
from tuners.cli import check_output_folder
from tuners.conventions import conform

if TYPE_CHECKING:  # the library is imported after parsing: --help answers before it loads
    from gripper_env.sysid.bus_servo import BusEstimate, BusRecord

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.identify",
        description="Fit a bus servo's loop (gain scales, motor, friction, delays) to records "
        "at several P settings, with uncertainties; writes the model file the tuner takes.",
    )
    parser.add_argument("records", nargs="+", type=Path, help="record files (tuners.bus.record)")
    parser.add_argument(
        "--model",
        default="sts3215",
        help="the family's model the fit starts from: sts3215, xl330, xl430 or a model file "
        "(default sts3215)",
    )
    parser.add_argument(
        "--name", default="identified", help="the model's name (default identified)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the global search")
    parser.add_argument(
        "--generations",
        type=int,
        default=80,
        help="generations of the global search, 16 candidates each (default 80)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default: the records' folder)"
    )
    parser.add_argument("--no-plot", action="store_true", help="do not draw NAME_fit.png")
    parser.add_argument(
        "--force",
        action="store_true",
        help="identify from records with a clipped step or more than 10 %% of their readings "
        "lost, and write a model whose fit to a record is under 90 %% (default: refuse, exit 1)",
    )
    parser.add_argument(
        "--quiet", action="store_true", help="no progress lines (the result is printed)"
    )
    return conform(parser, "tuners.bus.identify")


def format_estimate(est: BusEstimate) -> str:
    """A markdown table of the estimate: value, standard error, 95 % range."""
    from gripper_env.sysid.bus_servo import FIT_NAMES

    lines = ["| parameter | value | std | 95 % range |", "|---|---|---|---|"]
    ranges = est.ranges_95()
    for k in FIT_NAMES:
        v, s = est.values[k], est.std[k]
        if math.isfinite(s) and k in ranges:
            rng = f"{ranges[k][0]:.4g} to {ranges[k][1]:.4g}"
            lines.append(f"| {k} | {v:.4g} | {s:.2g} ({100 * s / abs(v):.1f} %) | {rng} |")
        else:
            lines.append(f"| {k} | {v:.4g} | not identified | kept at the prior |")
    lines.append(f"| goal delay | {est.delay_s * 1e3:.0f} ms | whole ticks | |")
    lines.append(f"| loop delay | {est.loop_delay_s * 1e3:.0f} ms | whole ticks | |")
    return "\n".join(lines)


def _plot(est: BusEstimate, records: list[BusRecord], names: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gripper_env.sysid.bus_servo import predict_record

    n = len(records)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n), squeeze=False)
    for ax, rec, name, fit in zip(axes[:, 0], records, names, est.per_record_fit, strict=True):
        ax.plot(rec.t_s, rec.goal_deg, "k--", lw=0.8, label="goal")
        ax.plot(rec.t_s, predict_record(est.model, rec), lw=1.2, label="identified model")
        ax.plot(rec.t_s, rec.position_deg, ".", ms=1.5, label="record")
        ax.set_title(f"{name}: {rec.registers.label()}, fit {fit:.1f} %", fontsize=9)
        ax.set_ylabel("deg")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _run(args: argparse.Namespace) -> int:
    if not 1 <= args.generations <= 10_000:
        raise ValueError(f"--generations must be 1..10000, got {args.generations}")
    safe_name(args.name, "--name")  # it names the files: never a path
    out = args.out or args.records[0].parent
    check_output_folder(out, "--out" if args.out else "the records' folder")
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.sysid.bus_experiments import check_record
    from gripper_env.sysid.bus_servo import identify_bus_servo, read_bus_record

    prior = load_bus_servo(args.model)
    records = [read_bus_record(p) for p in args.records]
    # the records' jaw calibration (the owner's jaw, their angles' frame) goes into the model
    calibration = records[0].calibration
    for path, rec in zip(args.records, records, strict=True):
        if rec.calibration != calibration:
            raise ValueError(
                f"{path} was recorded with another jaw calibration than {args.records[0]}: "
                "identify records of one servo and one calibration together"
            )
    prior = prior.calibrated(calibration)
    problems = [p for path, rec in zip(args.records, records, strict=True)
                for p in check_record(rec, str(path), prior)]  # fmt: skip
    if problems and not args.force:
        return _refuse(problems, "these records are not fit to identify from: record again "
                       "(the jaws empty, a quieter host), or pass --force")  # fmt: skip
    for text in problems:
        print(f"warning (--force): {text}", file=sys.stderr)

    def progress(text: str) -> None:
        if not args.quiet:
            print(text, flush=True)

    progress(f"identifying {args.name} from {len(records)} records (a few minutes on 2 cores)")
    est = identify_bus_servo(records, prior, name=args.name, seed=args.seed,
                             generations=args.generations, log=progress)  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"{args.name}_model"
    fits = zip(args.records, est.per_record_fit, strict=True)
    poor = [f"{path} fits only {fit:.1f} % (under 90 %)" for path, fit in fits if fit < 90]
    if poor and not args.force:
        if not args.no_plot:
            figure = stem.with_name(f"{args.name}_fit.png")
            _plot(est, records, [p.name for p in args.records], figure)
            poor.append(f"look at {figure}")
        return _refuse(poor, "the model is not written: the records do not fit the servo's "
                       "model (an object in the jaws, a slipping horn, a loaded host); record "
                       "again, or pass --force to write it anyway")  # fmt: skip
    doc = est.as_dict()
    doc["records"] = [str(p) for p in args.records]
    write_json(stem.with_suffix(".json"), doc)
    print(f"{args.name} ({prior.family}) from {len(records)} records: fit {est.fit_pct:.1f} %, "
          f"RMS error {est.rmse_deg:.3f} deg")  # fmt: skip
    print(format_estimate(est))
    for p in (16, 32, 64) if prior.family == "sts3215" else (200, 400, 800):
        print(f"dead band at P = {p}: {est.dead_band_deg(p):.2f} deg")
    for note in est.notes:
        print(f"note: {note}")
    for text in poor:
        print(f"warning (--force): {text}: look at the figure before trusting the model",
              file=sys.stderr)  # fmt: skip
    if not args.no_plot:
        _plot(est, records, [p.name for p in args.records], stem.with_name(f"{args.name}_fit.png"))
    print(f"wrote {stem.with_suffix('.json')}; next: python -m tuners.bus.tune --model "
          f"{stem.with_suffix('.json')}")  # fmt: skip
    return 0


def _refuse(problems: list[str], advice: str) -> int:
    """Print the problems and the advice, one line each, and return exit status 1."""
    prog = _parser().prog
    for text in problems:
        print(f"{prog}: error: {text}", file=sys.stderr)
    print(f"{prog}: error: {advice}", file=sys.stderr, flush=True)
    return EXIT_FAILURE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.identify``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

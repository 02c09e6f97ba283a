"""Identify the gripper as the paper did: ``python -m tuners.identify``.

``python -m tuners.identify [--simulate --plant test2 --disturbance actual --seed 0 | --port P]``

Runs the paper's Table-1 experiments open loop (test1 step; tests 2-4 slopes of 60, 40 and 20 s;
each grip and un-grip) on the simulated actual gripper or on the board, records each as CSV
(``t_s, desired_deg, actual_deg``, so ``python -m gripper_env.sysid LOG.csv`` reproduces each
fit), identifies each with ``tfest`` (2 poles, 1 zero), then validates every model against the
actual gripper's response to a common profile as the paper's stage 1 did (SD, SD gap, and fit %).
Writes ``results/identification.md`` (Table 1 and Table 2 beside the paper's numbers), the logs
and figures under ``results/identification/``, and with ``--save-plants DIR`` one plant file per
model (``ident_test2_slope60.yaml`` ...) that every command taking ``--plant`` accepts.

The pipeline lives in :mod:`gripper_env.sysid.experiments`; this module parses, picks the
recorder (simulated or device), and writes the report.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import os
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from gripper_env import __version__, paper
from gripper_env.disturbances import load_disturbance
from gripper_env.plants import Plant, load_plant
from gripper_env.references import PROFILES, Reference
from gripper_env.sysid.experiments import (
    EXPERIMENTS,
    QUICK_EXPERIMENTS,
    IdentificationRun,
    IdentifiedExperiment,
    Recorder,
    SimulatedRecorder,
    atomic_write_text,
    run_identification,
    save_plants,
    step_t63,
    validation_reference,
    write_reference_csv,
)
from gripper_env.sysid.tfest import format_polynomial

EXIT_BAD_INPUT = 2
RESULTS = Path(__file__).resolve().parent.parent / "results"
VALIDATION_HOLD_S = 60.0
QUICK_VALIDATION_HOLD_S = 10.0


class RecordingError(RuntimeError):
    """A recording could not be made (no recorder, or the device run failed)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser (every flag documented in ``--help``)."""
    p = _Parser(
        prog="python -m tuners.identify",
        description=(
            "Run the paper's Table-1 identification experiments (step; slopes of 60, 40, 20 s; "
            "grip and un-grip) open loop on the simulated actual gripper or on the board, "
            "identify each with tfest (2 poles, 1 zero), validate every model against the "
            "actual response (Table 2: SD, SD gap, fit %), and write identification.md, the CSV "
            "logs and figures."
        ),
        epilog="Exit status: 0 on success, 2 on bad input or a failed recording (one line on "
        "stderr).",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--simulate",
        action="store_true",
        help="record on the simulated actual gripper (--plant behind --disturbance); the "
        "default when --port is not given",
    )
    where.add_argument(
        "--port",
        default=None,
        help="record on the board at this serial port, through 'python -m tuners.record' "
        "(its defaults for calibration, boot wait and timeout)",
    )
    dev = p.add_argument_group("device options (with --port; passed to tuners.record)")
    dev.add_argument(
        "--calibration",
        default=None,
        metavar="FILE",
        help="calibration file from 'python -m tuners.calibrate' (default: tuners.record's)",
    )
    dev.add_argument(
        "--boot-wait",
        default=None,
        metavar="S",
        help="seconds to let the board boot after opening the port (default: tuners.record's)",
    )
    dev.add_argument(
        "--timeout",
        default=None,
        metavar="S",
        help="seconds to wait for each answer from the board (default: tuners.record's)",
    )
    p.add_argument(
        "--plant",
        default=None,
        help="simulated gripper's true transfer function: a plant name or YAML file "
        "(default: test2)",
    )
    p.add_argument(
        "--disturbance",
        default=None,
        help="simulated gripper's disturbance preset: a name or YAML file (default: actual)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="base noise seed of the simulated gripper; run k (test k+1, validation 4) uses "
        "seed + k (default: 0)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="short session for smoke tests: test1 (step) and test4 (slope20) only, validation "
        f"holds of {QUICK_VALIDATION_HOLD_S:g} s instead of {VALIDATION_HOLD_S:g} s",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=RESULTS,
        metavar="DIR",
        help="output folder: DIR/identification.md, logs and figures in DIR/identification/ "
        "(default: results/)",
    )
    p.add_argument(
        "--save-plants",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write each model as a plant file DIR/ident_<test>_<profile>.yaml",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the summary as JSON (experiments, validation, files, run time) instead of text",
    )
    return p


# ----------------------------------------------------------------------------------------------
# The device recorder: the colleague's tuners.record, imported lazily.


def device_recorder(port: str, device_args: Sequence[str] = (), quiet: bool = False) -> Recorder:
    """A :data:`~gripper_env.sysid.experiments.Recorder` on the board at ``port``.

    Each run calls ``python -m tuners.record --port PORT --profile P --output LOG.csv`` (in
    process); a profile that is not a named one is handed over as a CSV file.

    Parameters
    ----------
    port : str
        Serial port (or the virtual board's pty).
    device_args : sequence of str
        More arguments for ``tuners.record`` (``--calibration F``, ``--boot-wait S``, ...).
    quiet : bool
        Send the recorder's messages to stderr instead of stdout.

    Raises
    ------
    RecordingError
        ``tuners.record`` is not available on this branch.
    """
    if importlib.util.find_spec("tuners.record") is None:
        raise RecordingError(
            "hardware recording not available yet (tuners.record is not on this branch); "
            "use --simulate"
        )
    try:
        from tuners import record
    except ImportError as exc:
        raise RecordingError(f"hardware recording unavailable: {exc}") from None

    def _record(reference: Reference, path: Path, run: int = 0) -> Path:
        if reference.name in PROFILES:
            profile = reference.name
        else:
            profile = str(
                write_reference_csv(reference, path.with_name(f"{path.stem}_profile.csv"))
            )
        argv = ["--port", port, *device_args, "--profile", profile, "--output", str(path)]
        errors = io.StringIO()
        with (
            contextlib.redirect_stdout(sys.stderr if quiet else sys.stdout),
            contextlib.redirect_stderr(errors),
        ):
            try:
                status = record.main(argv)
            except SystemExit as exc:  # its argument parser refused something
                status = exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
        if status != 0:
            why = " ".join(errors.getvalue().split()) or f"exit status {status}"
            raise RecordingError(f"recording {reference.name} on {port} failed: {why}")
        return path

    return _record


# ----------------------------------------------------------------------------------------------
# Figures


def _save_figure(fig: Any, path: Path) -> Path:
    """Save a PNG atomically and close the figure."""
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fig.savefig(tmp, dpi=90, format="png")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)
    return path


def _moves(desired: np.ndarray, gap: int = 1000) -> list[tuple[int, int]]:
    """``(start, end)`` sample indices of each move of the desired angle (changes less than
    ``gap`` samples apart belong to one move, so a staircase ramp is one move)."""
    steps = np.flatnonzero(np.diff(desired) != 0) + 1
    if steps.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(steps) >= gap)
    starts = np.concatenate([[steps[0]], steps[breaks + 1]])
    ends = np.concatenate([steps[breaks], [steps[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _window(move: tuple[int, int], dt: float, n: int) -> slice:
    """Samples to show around a move: a step from just before it, a ramp around its arrival."""
    start, end = move
    if (end - start) * dt < 0.1:
        return slice(max(0, start - round(0.5 / dt)), min(n, start + round(3.5 / dt)))
    return slice(max(0, end - round(3.0 / dt)), min(n, end + round(2.0 / dt)))


def experiment_figure(item: IdentifiedExperiment, path: Path) -> Path:
    """Measured vs model response of one experiment: the grip and the un-grip move (a step
    from just before it, a ramp around its arrival), and the residuals of the whole record."""
    import matplotlib.pyplot as plt

    est = item.estimate
    t, u, y = item.t_s, item.desired_deg, item.actual_deg
    dt = float(t[1] - t[0])
    y_hat = est.simulate(u)
    moves = _moves(u)[:2]
    fig = plt.figure(figsize=(10, 6))
    grid = fig.add_gridspec(2, 2, height_ratios=[3, 1.3])
    for col, move in enumerate(moves):
        w = _window(move, dt, len(t))
        kind = "grip" if u[move[1]] < u[move[0] - 1] else "un-grip"
        ramp = (move[1] - move[0]) * dt >= 0.1
        ax = fig.add_subplot(grid[0, col])
        ax.plot(t[w], u[w], color="0.5", ls="--", lw=1, label="desired")
        ax.plot(t[w], y[w], color="C0", lw=0.8, label="measured (actual)")
        ax.plot(t[w], y_hat[w], color="C1", lw=1.3, label="model")
        ax.set(
            title=f"({'ab'[col]}) {kind}{': end of the ramp' if ramp else ' step'}",
            xlabel="time (s)",
        )
        ax.grid(alpha=0.3)
        if col == 0:
            ax.set_ylabel("jaw angle (deg)")
            ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[1, :])
    ax.plot(t, y - y_hat, color="C3", lw=0.6)
    ax.set(xlabel="time (s)", ylabel="measured - model (deg)", title="whole record")
    ax.grid(alpha=0.3)
    exp = item.experiment
    fig.suptitle(
        f"{exp.name} ({exp.description}): G(s) = {est.paper_form()}, fit {est.fit_pct:.2f} %",
        fontsize=10,
    )
    fig.tight_layout()
    return _save_figure(fig, path)


def validation_figure(run: IdentificationRun, path: Path) -> Path:
    """The paper's Figure 9: grip and un-grip responses of the actual gripper and each model."""
    import matplotlib.pyplot as plt

    val = run.validation
    t, u = val.t_s, val.desired_deg
    dt = float(t[1] - t[0])
    (grip, _), (ungrip, _) = _moves(u)[:2]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, start, title in ((axes[0], grip, "(a) grip"), (axes[1], ungrip, "(b) un-grip")):
        w = slice(max(0, start - round(0.5 / dt)), start + round(5.0 / dt))
        ax.plot(t[w], u[w], color="0.5", ls="--", lw=1, label="desired")
        ax.plot(t[w], val.actual_deg[w], color="C0", lw=1.4, label="actual (measured)")
        for i, (name, y_model) in enumerate(val.responses.items()):
            ax.plot(t[w], y_model[w], color=f"C{i + 1}", lw=1, label=f"model {name}")
        ax.set(title=title, xlabel="time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jaw angle (deg)")
    axes[1].legend(fontsize=8)
    fig.suptitle("Validation stage 1: direct response (the paper's Figure 9)", fontsize=10)
    fig.tight_layout()
    return _save_figure(fig, path)


# ----------------------------------------------------------------------------------------------
# Report


def _poles(poles: np.ndarray) -> str:
    return ", ".join(
        f"{p.real:.4g}{p.imag:+.3g}j" if abs(p.imag) > 0 else f"{p.real:.4g}"
        for p in sorted(poles, key=lambda p: p.real)
    )


def _paper_tf(name: str) -> str:
    num, den, _fit = paper.PLANTS[name]
    return f"({format_polynomial(num)}) / ({format_polynomial(den)})"


def render_report(
    run: IdentificationRun,
    *,
    command: str,
    validation_text: str,
    figures: dict[str, str],
    elapsed_s: float | None = None,
    true_plant: Plant | None = None,
    plant_files: Sequence[Path] = (),
) -> str:
    """The markdown report: Table 1 (identified TFs and fits) and Table 2 (validation).

    Parameters
    ----------
    run : IdentificationRun
        The session.
    command : str
        The command line that produced it.
    validation_text : str
        One sentence describing the validation profile.
    figures : dict
        ``"validation"`` and each test name -> figure path relative to the report.
    elapsed_s : float, optional
        Wall time of the session (s).
    true_plant : Plant, optional
        The simulated gripper's transfer function, when simulated.
    plant_files : sequence of Path
        Plant files written.
    """
    val = run.validation
    lines = [
        "# System identification: the paper's Table 1 and Table 2, rerun",
        "",
        f"Written by `{command}` (gripper-env {__version__}, "
        f"{datetime.now(UTC).strftime('%Y-%m-%d')})"
        + (f"; the session took {elapsed_s:.1f} s." if elapsed_s is not None else "."),
        "Paper: `shared/paper/`. Pipeline: `gripper_env.sysid.experiments`.",
        "",
        "The actual gripper:",
        "",
        "```",
        run.source,
        "```",
        "",
        "## 1. Experiments and identified transfer functions (Table 1, Figure 7)",
        "",
        "Each experiment runs open loop (the desired angle is the servo command), starting at",
        "rest at 92 deg; profiles as in `gripper_env.references` (the paper does not publish its",
        "timing): `step` = 1 s at 92, grip step to 21, 9 s, un-grip step to 92, 10 s; `slopeN` =",
        "1 s at 92, ramp to 21 over N s, 5 s hold, ramp back over N s, 5 s hold. Identification:",
        "`tfest` with 2 poles and 1 zero (the paper's structure), the model mapping deviations",
        "from the initial rest point, fit % like MATLAB's `compare` with the initial state",
        "estimated (the paper's *best fit*) and with a zero initial state. t63: time for the",
        "model's step response to cover 63.2 % of the commanded move (a speed summary that does",
        "not depend on the pole/zero structure).",
        "",
        "| test | input (desired) | samples | identified TF (ours) | fit % | fit % (zero IC) | poles (rad/s) | DC gain | t63 (s) | paper TF | paper fit % |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for item in run.experiments:
        est, exp = item.estimate, item.experiment
        flag = "" if est.stable else " **unstable**"
        lines.append(
            f"| {exp.name} | {exp.description} | {item.t_s.size} | {est.paper_form()}{flag} | "
            f"{est.fit_pct:.2f} | {est.fit_pct_zero_ic:.2f} | {_poles(est.poles)} | "
            f"{item.dc_gain:.3f} | {item.t63_s:.3f} | {_paper_tf(exp.name)} | "
            f"{paper.PLANTS[exp.name][2]} |"
        )
    lines.append("")
    if true_plant is not None:
        t63 = step_t63(true_plant.num, true_plant.den, true_plant.dt_s)
        lines += [
            f"The simulated gripper's own transfer function ({true_plant.name}) is "
            f"({format_polynomial(true_plant.num)}) / ({format_polynomial(true_plant.den)}): "
            f"poles {_poles(true_plant.poles)} rad/s, t63 = {t63:.3f} s.",
        ]
        slopes = [i for i in run.experiments if i.experiment.profile.startswith("slope")]
        if slopes and all(i.t63_s > 2 * t63 for i in slopes):
            lines += [
                "Every slope model is more than twice as slow as the true plant: friction and",
                "whole-degree servo commands make the jaw lag a slow ramp, and a linear model",
                "absorbs that lag into its dynamics (on `--disturbance ideal` the same experiments",
                "recover the plant's poles; `tests/sysid/test_identify.py`).",
            ]
        lines.append("")
    lines += [
        "Each fit is reproducible from its log: `python -m gripper_env.sysid "
        "results/identification/<test>_<profile>.csv` (logs are written by this command, not "
        "committed).",
        "",
    ]
    for item in run.experiments:
        name = item.experiment.name
        lines.append(f"![{name}: measured vs model]({figures[name]})")
    lines += [
        "",
        "## 2. Validation stage 1: direct response (Table 2, Figure 9)",
        "",
        validation_text,
        "Every identified model is driven by the same desired angle as identified (at rest at",
        "its operating point). SD is the sample standard deviation of the angle over the run",
        "(ddof = 1); SD_Actual - SD_Test is the paper's column (signed); fit % is MATLAB's",
        "`compare` fit of the model's response to the actual measured one; *fit % as plant file*",
        "is the same model used the way plant files are (absolute angles from rest at 92 deg).",
        "",
        "| Data | Standard Deviation (SD) | SD_Actual - SD_Test | \\|SD gap\\| | fit % to actual | fit % as plant file | paper SD | paper SD_Actual - SD_Test |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|",
        f"| Actual | {val.sd_actual_deg:.3f} | | | | | {paper.TABLE2_SD['actual']} | |",
    ]
    for row in val.rows:
        paper_sd = paper.TABLE2_SD[row.name]
        lines.append(
            f"| Test {row.name.removeprefix('test')} | {row.sd_deg:.3f} | {row.sd_gap_deg:.3f} | "
            f"{row.abs_sd_gap_deg:.3f} | {row.fit_pct:.2f} | {row.fit_pct_plant:.2f} | "
            f"{paper_sd:.3f} | {paper.TABLE2_SD['actual'] - paper_sd:.3f} |"
        )
    agree = "agree" if val.criteria_agree else "**disagree**"
    by_gap = " < ".join(r.name for r in sorted(val.rows, key=lambda r: r.abs_sd_gap_deg))
    by_fit = " > ".join(r.name for r in sorted(val.rows, key=lambda r: -r.fit_pct))
    lines += [
        "",
        f"Best model by the paper's criterion (smallest |SD gap|): **{val.best_by_sd_gap}**; by "
        f"fit %: **{val.best_by_fit}**. The two criteria {agree} on the best model (the paper "
        f"chose test2 by SD gap). Full rankings: |SD gap| {by_gap}; fit % {by_fit}.",
        "An SD compares only the spread of two responses, not their shape in time: it",
        "cannot see a lag or an offset that leaves the spread unchanged, and a gap of a few",
        "hundredths of a degree is within run-to-run noise; fit % compares the responses sample",
        "by sample.",
        "",
        "The paper's four transfer functions on the same validation run (absolute angles, the TF",
        "alone, as `tuners.reproduce` drives them):",
        "",
        "| paper TF | SD | SD_Actual - SD_Test | fit % to actual |",
        "|---|---|---|---|",
    ]
    for row in val.paper_rows:
        lines.append(
            f"| {row.name} | {row.sd_deg:.3f} | {row.sd_gap_deg:.3f} | {row.fit_pct:.2f} |"
        )
    lines += ["", f"![Figure 9: direct response]({figures['validation']})", ""]
    if plant_files:
        lines += ["## 3. Plant files", ""]
        lines += [f"- `{p}`" for p in plant_files]
        lines += [
            "",
            "Each loads with `gripper_env.plants.load_plant(PATH)` and runs wherever a plant is",
            "accepted (`--plant PATH`). A plant file holds the transfer function only: the",
            "operating point it was identified about is in its description.",
            "",
        ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Entry point


def _command(args: argparse.Namespace) -> str:
    parts = ["python -m tuners.identify"]
    if args.port:
        parts.append(f"--port {args.port}")
    else:
        parts.append(f"--simulate --plant {args.plant} --disturbance {args.disturbance}")
        parts.append(f"--seed {args.seed}")
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def _run(args: argparse.Namespace, started: float) -> dict[str, Any]:
    true_plant = None
    if args.port:
        device_args = [
            arg
            for flag, value in (
                ("--calibration", args.calibration),
                ("--boot-wait", args.boot_wait),
                ("--timeout", args.timeout),
            )
            if value is not None
            for arg in (flag, value)
        ]
        recorder = device_recorder(args.port, device_args, quiet=args.json)
        source = f"the board at {args.port} (python -m tuners.record)"
    else:
        true_plant = load_plant(args.plant)
        sim = SimulatedRecorder(true_plant, load_disturbance(args.disturbance), args.seed)
        recorder, source = sim, sim.describe()
    hold = QUICK_VALIDATION_HOLD_S if args.quick else VALIDATION_HOLD_S
    log_dir = args.out / "identification"
    say = (lambda _m: None) if args.json else print
    run = run_identification(
        recorder,
        log_dir,
        QUICK_EXPERIMENTS if args.quick else EXPERIMENTS,
        validation_reference(hold),
        source=source,
        progress=say,
    )
    import matplotlib

    matplotlib.use("Agg")
    figures = {
        item.experiment.name: experiment_figure(item, log_dir / f"{item.experiment.label}.png")
        for item in run.experiments
    }
    figures["validation"] = validation_figure(run, log_dir / "validation.png")
    plant_files = (
        save_plants(run, args.save_plants, source.splitlines()[0]) if args.save_plants else []
    )
    report_path = args.out / "identification.md"
    text = render_report(
        run,
        command=_command(args),
        validation_text=(
            f"Validation profile: 1 s at 92 deg (open), grip step to 21 deg, {hold:g} s hold, "
            f"un-grip step to 92 deg, {hold:g} s hold ({1 + 2 * hold:g} s; the profile of "
            "`tuners.reproduce` section 2). The paper does not publish its validation profile."
        ),
        figures={k: os.path.relpath(v, report_path.parent) for k, v in figures.items()},
        elapsed_s=time.perf_counter() - started,
        true_plant=true_plant,
        plant_files=plant_files,
    )
    atomic_write_text(report_path, text)
    summary = run.to_dict()
    summary.update(
        command=_command(args),
        report=str(report_path),
        figures={k: str(v) for k, v in figures.items()},
        plant_files=[str(p) for p in plant_files],
        elapsed_s=time.perf_counter() - started,
    )
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    started = time.perf_counter()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.port is not None:
        given = [f for f in ("plant", "disturbance", "seed") if getattr(args, f) is not None]
        if given:
            parser.error(f"--{', --'.join(given)} go with --simulate, not --port")
        if not args.port.strip():
            parser.error("--port needs a serial port name")
    else:
        given = [f for f in ("calibration", "boot_wait", "timeout") if getattr(args, f)]
        if given:
            flags = ", --".join(f.replace("_", "-") for f in given)
            parser.error(f"--{flags} go with --port, not --simulate")
    args.plant = "test2" if args.plant is None else args.plant
    args.disturbance = "actual" if args.disturbance is None else args.disturbance
    args.seed = 0 if args.seed is None else args.seed
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    try:
        summary = _run(args, started)
    except (ValueError, OSError, RecordingError) as exc:
        print(f"{parser.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {summary['report']} and {len(summary['figures'])} figures")
        for p in summary["plant_files"]:
            print(f"wrote {p}")
        print(f"done in {summary['elapsed_s']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

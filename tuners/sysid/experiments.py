"""``python -m tuners.sysid experiments``: the paper's identification session end to end.

``python -m tuners.sysid experiments [--simulate --plant test2 | --port P] [--quick]``

Runs the paper's Table-1 experiments open loop (test1 step; tests 2-4 slopes of 60, 40 and 20 s;
each grip and un-grip) on the simulated actual gripper or on the board, records each as CSV
(``t_s, desired_deg, actual_deg``, so ``python -m tuners.sysid LOG.csv`` reproduces each
fit), identifies each (2 poles, 1 zero and a delay), validates every model against the actual
gripper's response to a common profile as the paper's stage 1 did (SD, SD gap, fit % on that
validation record), and identifies the actual gripper itself -- friction, sensor, delay -- with
the simulation core. Writes ``identification.md``, the logs and figures under
``identification/``, and with ``--save-plants DIR`` one plant file per model plus the identified
actual gripper (``actual_<test>.yaml`` plant and preset).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from tuners.sysid.common import BAD_INPUT, errors_as_exit_2, safe_print

__all__ = ["add_parser", "run"]

PROG = "python -m tuners.sysid experiments"
RUNS = Path("runs")  # of the working directory, like every command's (results: --out results)
VALIDATION_HOLD_S = 60.0
QUICK_VALIDATION_HOLD_S = 10.0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """The ``experiments`` subcommand's parser."""
    p = sub.add_parser(
        "experiments",
        help="the paper's Table-1 experiments end to end (simulated or on the board)",
        description=(
            "Run the paper's Table-1 identification experiments (step; slopes of 60, 40, 20 s; "
            "grip and un-grip) open loop on the simulated actual gripper or on the board, "
            "identify each (2 poles, 1 zero, delay), validate every model against the actual "
            "response (Table 2: SD, SD gap, fit % on the validation record), identify the "
            "actual gripper (friction, sensor, delay) with the simulation core, and write "
            "identification.md, the CSV logs and figures."
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
    where.add_argument("--port", default=None, help="record on the board at this serial port")
    dev = p.add_argument_group("device options (with --port)")
    for flag, kind, metavar, text in (
        ("--calibration", str, "FILE", "calibration file from 'python -m tuners.rig.calibrate'"),
        ("--boot-wait", float, "S", "seconds to let the board boot after opening the port (2)"),
        ("--timeout", float, "S", "seconds to wait for each answer from the board (0.5)"),
    ):
        dev.add_argument(flag, type=kind, default=None, metavar=metavar, help=text)
    for flag, convert, text in (
        ("--plant", str, "simulated gripper's transfer function: plant name or YAML (test2)"),
        ("--disturbance", str, "simulated gripper's preset: a name or YAML file (actual)"),
        ("--seed", int, "base noise seed; run k (test k+1, validation 4) uses seed + k (0)"),
    ):
        p.add_argument(flag, type=convert, default=None, help=text)
    p.add_argument(
        "--quick",
        action="store_true",
        help="short session for smoke tests: test1 (step) and test4 (slope20) only, validation "
        f"holds of {QUICK_VALIDATION_HOLD_S:g} s instead of {VALIDATION_HOLD_S:g} s",
    )
    p.add_argument("--no-greybox", action="store_true",
                   help="skip the identification of the actual gripper with the core")  # fmt: skip
    p.add_argument("--out", type=Path, default=RUNS, metavar="DIR",
                   help="output folder: DIR/identification.md, logs and figures in "
                   "DIR/identification/ (default: runs/; the committed report: --out "
                   "results)")  # fmt: skip
    p.add_argument("--save-plants", type=Path, default=None, metavar="DIR",
                   help="also write each model as a plant file DIR/ident_<test>_<profile>.yaml, "
                   "and the actual gripper as DIR/actual_<test>_<profile>.yaml plus "
                   "DIR/actual_<test>_<profile>_preset.yaml")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the summary as JSON (experiments, "
                   "validation, actual gripper, files, run time) instead of text")  # fmt: skip
    p.set_defaults(run=run)
    return p


def _check(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
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


def _command(args: argparse.Namespace) -> str:
    parts = ["python -m tuners.sysid experiments"]
    if args.port:
        parts.append(f"--port {args.port}")
    else:
        parts.append(f"--simulate --plant {args.plant} --disturbance {args.disturbance}")
        parts.append(f"--seed {args.seed}")
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def _session(args: argparse.Namespace, started: float) -> dict[str, Any]:
    from gripper_env.io.files import collect_provenance, write_atomic
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.plants import load_plant
    from gripper_env.sysid.experiments import (
        EXPERIMENTS,
        QUICK_EXPERIMENTS,
        DeviceRecorder,
        SimulatedRecorder,
        validation_reference,
    )
    from gripper_env.sysid.report import (
        actual_figure,
        experiment_figure,
        render_report,
        validation_figure,
    )
    from gripper_env.sysid.session import run_identification, save_actual, save_plants

    true_plant = truth = None
    say = (lambda _m: None) if args.json else print
    if args.port:
        recorder: Any = DeviceRecorder(
            args.port,
            args.calibration,
            2.0 if args.boot_wait is None else args.boot_wait,
            0.5 if args.timeout is None else args.timeout,
            progress=lambda m: print(m, file=sys.stderr),
        )
        source = recorder.describe()
    else:
        true_plant, truth = load_plant(args.plant), load_disturbance(args.disturbance)
        recorder = SimulatedRecorder(true_plant, truth, args.seed)
        source = recorder.describe()
    hold = QUICK_VALIDATION_HOLD_S if args.quick else VALIDATION_HOLD_S
    log_dir = args.out / "identification"
    # one provenance sidecar for the session: identification.provenance.json
    with collect_provenance(args.out, "identification", command=_command(args),
                            started=started) as prov:  # fmt: skip
        run = run_identification(
            recorder, log_dir, QUICK_EXPERIMENTS if args.quick else EXPERIMENTS,
            validation_reference(hold), source=source, progress=say, greybox=not args.no_greybox,
        )  # fmt: skip
        import matplotlib

        matplotlib.use("Agg")
        figures = {
            item.experiment.name: experiment_figure(item, log_dir / f"{item.experiment.label}.png")
            for item in run.experiments
        }
        figures["validation"] = validation_figure(run, log_dir / "validation.png")
        if run.actual is not None:
            figures["actual"] = actual_figure(run, log_dir / "actual.png")
        files = []
        if args.save_plants:
            files = save_plants(run, args.save_plants, source.splitlines()[0])
            if run.actual is not None:
                stem = f"actual_{run.actual_from}"
                files += save_actual(
                    run.actual, args.save_plants / f"{stem}.yaml",
                    args.save_plants / f"{stem}_preset.yaml", name=stem,
                    source=f"{run.actual_from}.csv", command=_command(args),
                )  # fmt: skip
        report_path = args.out / "identification.md"
        text = render_report(
            run,
            command=_command(args),
            validation_text=(
                f"Validation profile: 1 s at 92 deg (open), grip step to 21 deg, {hold:g} s hold, "
                f"un-grip step to 92 deg, {hold:g} s hold ({1 + 2 * hold:g} s; the profile of "
                "`gripper_env.paper` section 2). The paper does not publish its validation profile."
            ),
            figures={k: os.path.relpath(v, report_path.parent) for k, v in figures.items()},
            true_plant=true_plant,
            truth=truth,
            plant_files=files,
        )
        write_atomic(report_path, text)
        if run.actual is not None:
            prov.extra["greybox_s"] = run.actual.elapsed_s
        summary = run.to_dict()
        summary.update(
            command=_command(args),
            report=str(report_path),
            figures={k: str(v) for k, v in figures.items()},
            plant_files=[str(p) for p in files],
            elapsed_s=time.perf_counter() - started,
        )
    return summary


def run(args: argparse.Namespace) -> int:
    """Run the ``experiments`` command; returns the exit status."""
    from gripper_env.hardware.host.calibration import CalibrationError
    from gripper_env.hardware.host.errors import DeviceError

    started = time.perf_counter()
    _check(args, args.parser)
    try:
        summary = _session(args, started)
    except (*BAD_INPUT, DeviceError, CalibrationError) as exc:
        return errors_as_exit_2(PROG, exc)
    if args.json:
        safe_print(json.dumps(summary, indent=2))
    else:
        print(f"wrote {summary['report']} and {len(summary['figures'])} figures")
        for p in summary["plant_files"]:
            print(f"wrote {p}")
        print(f"done in {summary['elapsed_s']:.1f} s")
    return 0

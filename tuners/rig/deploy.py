"""Deploy tuned gains to the board's PID and compare the measured response with the prediction.

``python -m tuners.rig.deploy --gains results/test2/optuna.json --port P [--profile step]``

Recipe:

1. read the gains file (:mod:`gripper_env.model.gains_file`: plant, P, I, D, N, sign, limits);
2. **stability gate**: refuse (exit 2) gains whose closed loop is unstable on the gains file's
   plant as the board runs it, with the servo's 20 ms command hold
   (:func:`gripper_env.evaluation.stability.stability_report`), unless ``--allow-unstable``; warn
   when
   they are stable but miss the tuners' robustness constraints;
3. configure the board (gains, limits, sign, anti-windup, calibration) and run the profile in
   closed loop on the board's PID, the host streaming the reference at 50 Hz; the log
   ``response.csv`` (``t_s, reference_deg, command_deg, position_deg``) is written as it goes
   (``response.partial.csv`` until the run completes);
4. simulate the same reference as the board applied it with the same controller on the
   plant and disturbance preset (the prediction), compute the same metrics for both and the
   fit % of the measured response to the prediction; write ``report.json`` and
   ``response.png`` next to the log.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripper_env.io.files import path_in, safe_name, save_figure, write_json
from gripper_env.model.references import PROFILES
from tuners.cli import DEFAULT_OUT, check_output_folder
from tuners.conventions import command_parser
from tuners.rig.cli import add_device_arguments, given_calibration, run_cli

if TYPE_CHECKING:  # the library is imported where it is used: --help answers before it loads
    from gripper_env.evaluation.objective import Constraints
    from gripper_env.evaluation.stability import StabilityReport
    from gripper_env.hardware.host.experiment import RecordedTrajectory
    from gripper_env.hardware.host.telemetry import TelemetryBlock
    from gripper_env.model.disturbances import Disturbance
    from gripper_env.model.pid import PIDGains, PIDOptions
    from gripper_env.model.plants import Plant
    from gripper_env.sim import Trajectory

__all__ = ["main", "prediction"]


def deploy_rows(block: TelemetryBlock, t0_us: int) -> np.ndarray:
    """CSV rows ``t_s, reference_deg, command_deg, position_deg`` of a telemetry block."""
    return np.column_stack(
        [(block.t_us - t0_us) / 1e6, block.reference_deg, block.command_deg, block.position_deg]
    )


def _plot(path: Path, measured: RecordedTrajectory, predicted: Any, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(measured.t, measured.r[0], "k--", lw=1, label="reference")
    ax.plot(predicted.t, predicted.y[0], lw=1.2, label="predicted (simulation)")
    ax.plot(measured.t, measured.y[0], lw=1.2, label="measured (board)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("jaw angle (deg)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _parser() -> argparse.ArgumentParser:
    parser = command_parser(
        "tuners.rig.deploy",
        "Run tuned gains on the board's PID behind a stability gate, log the response, and "
        "compare it with the simulation's prediction.",
    )
    parser.add_argument("--gains", required=True, metavar="FILE", help="gains file (JSON)")
    add_device_arguments(parser)
    parser.add_argument(
        "--profile",
        default="step",
        help=f"reference profile: {', '.join(PROFILES)}, or a CSV file (default: step)",
    )
    parser.add_argument(
        "--disturbance",
        default="actual",
        help="actual-gripper preset of the prediction (default: actual)",
    )
    parser.add_argument(
        "--objective",
        default=None,
        metavar="YAML",
        help="the objective whose robustness constraints the gate warns against "
        "(default: configs/objective.yaml)",
    )
    parser.add_argument(
        "--allow-unstable",
        action="store_true",
        help="run even if the closed loop is unstable on the gains file's plant (the gate "
        "refuses such gains by default); the board's watchdog and jaw clamp still apply",
    )
    parser.add_argument(
        "--output-dir",
        default=None,
        metavar="DIR",
        help="where response.csv, report.json and response.png go "
        "(default: runs/hardware/deploy_PLANT_TUNER_PROFILE)",
    )
    parser.add_argument("--no-plot", action="store_true", help="skip response.png")
    return parser


def _gate(
    model: Plant,
    plant: str,
    gains: PIDGains,
    options: PIDOptions,
    allow_unstable: bool,
    *,
    disturbance: Disturbance,
    constraints: Constraints,
) -> StabilityReport:
    """The stability gate: refuse (ValueError) gains unstable on ``model`` (named ``plant``) as
    the board runs them, unless ``allow_unstable``; warn when they are stable but not robust.
    Returns the :func:`~gripper_env.evaluation.stability.stability_report`."""
    from gripper_env.evaluation.stability import stability_report

    # PID at 1 ms, servo command held 20 ms
    report = stability_report(model, gains, options.sign, disturbance=disturbance)
    if not report.stable and not allow_unstable:
        raise ValueError(
            f"refusing to deploy: P={gains.P:g} I={gains.I:g} D={gains.D:g} N={gains.N:g} "
            f"(sign {options.sign:+d}) give an unstable closed loop on plant {plant} with the "
            f"servo's {report.refresh_period_s * 1e3:g} ms command hold (largest |z| "
            f"{report.max_pole_magnitude:.4f} >= 1); pass --allow-unstable to run anyway"
        )
    if not report.stable:
        print(f"warning: running gains that are unstable on plant {plant}", file=sys.stderr)
    else:
        lim = constraints
        if not report.meets(lim.ms_max, lim.gm_min_db):
            gm = report.gain_margin_db
            print(
                f"warning: these gains are stable but not robust on plant {plant} with the "
                f"servo's hold (Ms {report.ms:.2f}, gain margin "
                f"{'inf' if gm is None else f'{gm:.1f}'} dB; the tuners require Ms <= "
                f"{lim.ms_max:g} and >= {lim.gm_min_db:g} dB)",
                file=sys.stderr,
            )
    return report


def prediction(
    model: Plant,
    measured: Trajectory,
    gains: PIDGains,
    options: PIDOptions,
    disturbance: str | Disturbance = "actual",
) -> tuple[Trajectory, float]:
    """What the simulation predicts for a recorded closed-loop run, and the fit (%) of the
    measured angle to it: ``model`` under ``gains`` on the run's own reference, from its first
    measured angle, with the run's grip and un-grip segments for the metrics."""
    from gripper_env.evaluation.metrics import fit_percent
    from gripper_env.sim import simulate

    predicted = simulate(
        model,
        measured.r[0],
        gains=[gains.as_array()],
        disturbance=disturbance,
        pid_options=options,
        y0_deg=float(measured.y[0, 0]),
    )
    predicted.reference = measured.reference  # same segments for the metrics
    return predicted, float(fit_percent(measured.y[0], predicted.y[0]))


def settling_band(
    measured: Trajectory, calibration: Any, objective: Any, disturbance: str
) -> dict[str, Any]:
    """The settling band's floor (deg) for a record of the rig, and how it is made up: the
    objective's floor on the prediction's preset (the friction band the jaw may rest anywhere
    in), plus what the reading itself leaves (:func:`~gripper_env.evaluation.metrics.
    reading_band_deg`: one ADC count of the calibration, and three times the reading's noise).
    The metrics take ``max(2 % of the move, floor)``; the measured and the predicted response
    are judged in the same band."""
    from gripper_env.evaluation.metrics import reading_band_deg
    from gripper_env.model.disturbances import load_disturbance

    resolution = 71.0 / abs(calibration.adc_at_92_deg - calibration.adc_at_21_deg)  # deg/count
    reading, noise = reading_band_deg(measured.y[0], resolution)
    friction = float(objective.settling_band_deg(load_disturbance(disturbance)))
    floor = friction + reading
    text = (
        f"+/-{floor:.2f} deg at least: the {disturbance} preset's friction band {friction:.2f} deg "
        f"+ the reading's {resolution:.2f}-deg ADC step + 3 x its {noise:.2f}-deg noise; "
        "2 % of a move where wider"
    )
    return {
        "floor_deg": floor,
        "friction_band_deg": friction,
        "adc_step_deg": resolution,
        "reading_noise_sd_deg": noise,
        "text": text,
    }


def _run(args: argparse.Namespace) -> int:
    from gripper_env.hardware.host.calibration import board_calibration, load_calibration
    from gripper_env.io.config import MAX_DATA_BYTES, check_input
    from gripper_env.model.gains_file import GainsFileError, load_gains_file

    loaded = load_gains_file(args.gains)
    plant, tuner, gains, options = loaded.plant, loaded.tuner, loaded.gains, loaded.options
    # the file's names are checked before the gate's work and its imports (python-control)
    safe_name(tuner or "gains", "tuner")
    if plant:
        safe_name(plant, "plant name")
    # a pipe, a device or an oversized file as the calibration: refused before the gate's work
    # (a missing one after it: the gate's verdict on the gains stands without a rig)
    cal_path, cal_option = given_calibration(args)
    if cal_path is not None:
        check_input(cal_path, MAX_DATA_BYTES, "calibration file", cal_option, missing_ok=True)
    from gripper_env.evaluation.metrics import compute_metrics
    from gripper_env.evaluation.objective import load_objective
    from gripper_env.hardware.host.device import GripperDevice
    from gripper_env.hardware.host.experiment import CsvLog, run_profile
    from gripper_env.hardware.protocol import Mode
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.references import load_reference
    from gripper_env.sim import Trajectory

    try:
        model = loaded.plant_model()  # the transfer function tuned on, wherever it came from
    except GainsFileError as exc:
        raise ValueError(f"{args.gains}: {exc} (needed for the gate)") from None
    plant = plant or model.name
    # the gate judges the loop as the board runs it: the actual servo's 20 ms command hold and
    # sensor delay, whatever preset the prediction uses
    report = _gate(
        model, plant, gains, options, args.allow_unstable,
        disturbance=load_disturbance("actual"),
        constraints=load_objective(args.objective).constraints,
    )  # fmt: skip
    reference = load_reference(args.profile)
    if args.output_dir:
        out_dir = Path(args.output_dir)
    else:  # names from the gains file: one plain path component each (gripper_env.io.files)
        name = f"deploy_{safe_name(plant, 'plant name')}_{safe_name(tuner or 'gains', 'tuner')}"
        out_dir = path_in(DEFAULT_OUT / "hardware", f"{name}_{reference.name}", what="profile")
    check_output_folder(out_dir, "--output-dir")  # before the board moves
    given = None if cal_path is None else load_calibration(cal_path, cal_option)
    # the log's columns: a Trajectory's CSV columns
    log = CsvLog(out_dir / "response.csv", Trajectory.CSV_COLUMNS, deploy_rows)
    with GripperDevice(args.port, boot_wait_s=args.boot_wait, timeout_s=args.timeout) as device:
        device_id = device.info.device_id if device.info else None
        # the board's own calibration, or the given one if it is this board's: refused before
        # the first CONFIGURE and before anything is written
        calibration = board_calibration(device_id, args.port, given, f"{cal_option} {cal_path}")
        out_dir.mkdir(parents=True, exist_ok=True)
        device.configure(gains, options, calibration=calibration)
        rec = run_profile(device, reference, Mode.CLOSED_LOOP, log=log)
    measured = rec.trajectory()
    predicted, fit = prediction(model, measured, gains, options, args.disturbance)
    band = settling_band(measured, calibration, load_objective(args.objective), args.disturbance)
    content = {
        "plant": plant,
        "tuner": tuner,
        "gains": {"P": gains.P, "I": gains.I, "D": gains.D, "N": gains.N},
        "sign": options.sign,
        "profile": reference.name,
        "disturbance": args.disturbance,
        "stability": report.as_dict(),
        "fit_pct": fit,
        "settling_band": band,
        "measured": compute_metrics(measured, settling_band_deg=band["floor_deg"]).as_dict(),
        "predicted": compute_metrics(predicted, settling_band_deg=band["floor_deg"]).as_dict(),
        "link": {
            "samples": len(rec.samples),
            "missing_samples": measured.missing_samples,
            "frames_lost": rec.frames_lost,
            "host_periods": rec.host_periods,
            "missed_deadlines": rec.missed_deadlines,
        },
        "calibration": calibration.to_dict(),
        "gains_file": str(args.gains),
        "port": args.port,
        "log": rec.extra.get("log"),
    }
    write_json(out_dir / "report.json", content)
    if not args.no_plot:
        _plot(
            out_dir / "response.png",
            measured,
            predicted,
            f"{tuner or 'gains'} on {plant}, {reference.name}: fit {fit:.1f} % to the prediction",
        )
    m = content["measured"]
    print(
        f"deployed {tuner or args.gains} on {args.port}: fit {fit:.1f} % to the prediction, "
        f"grip overshoot {m['grip']['overshoot_pct']:.1f} %, settling "
        f"{m['grip']['settling_time_s']:.3g} s (within {band['text']}), {rec.frames_lost} "
        f"frames lost -> {out_dir}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rig.deploy``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

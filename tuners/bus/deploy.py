"""``python -m tuners.bus.deploy``: write tuned registers to a bus servo behind a gate, verify
them, compare the servo's response with the model's prediction, and save them only if asked.

Recipe:

1. read the registers file of ``python -m tuners.bus.tune`` (the registers and the model they
   were tuned on, with its uncertainties and the owner's jaw calibration, or ``--jaw``);
2. **gate**: judge the registers on that model (:func:`gripper_env.evaluation.bus_servo.judge`:
   the loop's margins, free and on an object, over the model's uncertainty corners; the grasp and
   hold without tripping the protection the servo's registers set, as read at calibration).
   Refuse (exit 2) registers that fail: an unstable loop always, the rest unless
   ``--allow-infeasible``; refuse a verification (or hold) that leaves the calibrated jaw's goal
   range;
3. find the servo of ``--id`` (nothing is sent to the others), check its calibration against
   the jaw calibration's and its maximum torque limit against the tuned torque limit, read its
   protection registers (``Overload_Torque``, ``Protection_Time``, ``Protection_Current``...;
   a Dynamixel's ``Shutdown``), judge again if the owner changed them since, and snapshot the
   registers the deploy writes;
4. write the registers with the torque off (an STS3215's with ``Lock`` = 1: not saved to flash)
   and read each back;
5. run the verification: the tuner's tracking steps (4 to 44 deg, both ways), the position read
   over the bus; with ``--hold S``, close on the object in the jaws and hold S seconds. An error
   bit in any reply (an overload: TRIPPED) stops the deploy: torque off, registers restored, the
   report written, exit 1;
6. simulate the same goal writes on the model (the prediction), and write ``response.csv`` (the
   record), ``report.json`` (fit % to the prediction, per-step errors, the hold) and
   ``response.png`` to ``--out``;
7. with ``--save``, keep the registers: an STS3215's P, D, I and dead zones are saved to its
   flash, once (``Lock`` = 0 for one write per group of adjacent registers); the RAM registers
   (torque limit, acceleration, velocity; all of a Dynamixel's) keep their values until the
   servo is switched off. Without it the deploy is a trial: every register is restored as found
   and read back. The torque ends as it was found unless ``--keep-torque``.

Examples
--------
``python -m tuners.bus.deploy --registers runs/bus/sts3215/my-sts3215_registers.json --port P
--id 6 --hold 10 --save``
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gripper_env.hardware.bus.link import BusAlertError, BusError
from gripper_env.io.files import write_json
from tuners.bus.cli import (
    BusArgumentParser,
    add_servo_arguments,
    load_jaw,
    open_gripper,
    output_folder,
    run_cli,
)
from tuners.conventions import conform

if TYPE_CHECKING:  # the library is imported where it is used: --help answers before it loads
    import numpy as np

    from gripper_env.evaluation.bus_servo import BusScore
    from gripper_env.hardware.bus.gripper import BusGripper
    from gripper_env.model.bus_servo import BusServoModel, RegisterSet
    from gripper_env.sysid.bus_experiments import BusRecorder, GoalPlan
    from gripper_env.sysid.bus_servo import BusRecord

__all__ = ["gate", "main"]


def gate(
    model: BusServoModel,
    regs: RegisterSet,
    rel_std: dict[str, float] | None,
    allow_infeasible: bool = False,
    alternatives: Sequence[BusServoModel] = (),
) -> BusScore:
    """Judge ``regs`` on ``model`` (and its ``alternatives``, the identification's fits at later
    loop delays); refuse (ValueError) an unstable loop, and registers that miss the constraints
    unless ``allow_infeasible`` (then warn)."""
    from gripper_env.evaluation.bus_servo import judge

    score = judge(model, [regs], rel_std=rel_std, alternatives=alternatives)[0]
    if not score.robust_margins.stable:
        raise ValueError(
            f"refusing to deploy {regs.label()}: the loop is unstable on the {model.name} model "
            "or one of its uncertainty corners"
        )
    if not score.feasible:
        why = "; ".join(score.violations)
        if not allow_infeasible:
            raise ValueError(
                f"refusing to deploy {regs.label()} on the {model.name} model: {why} (pass "
                "--allow-infeasible to write them anyway)"
            )
        print(f"warning: deploying registers that miss the constraints: {why}", file=sys.stderr)
    return score


def _step_errors(rec: BusRecord, predicted: np.ndarray) -> list[dict[str, float]]:
    """Per step: the goal, and the measured and predicted angle at its end (deg)."""
    import numpy as np

    out = []
    ends = [*rec.goal_times_s[1:], rec.t_s[-1] + 1e-9]
    for t_start, goal, t_end in zip(rec.goal_times_s, rec.goal_values_deg, ends, strict=False):
        idx = np.flatnonzero((rec.t_s >= t_start) & (rec.t_s < t_end))
        if idx.size == 0:
            continue
        last = int(idx[-1])
        out.append({
            "goal_deg": float(goal),
            "measured_deg": float(rec.position_deg[last]),
            "predicted_deg": float(predicted[last]),
        })  # fmt: skip
    return out


def _hold(jaw: BusGripper, seconds: float) -> dict[str, Any]:
    """Close on the object and hold ``seconds``, watching the error bits: position, and the
    first error with when it came (the torque then goes off at once and the hold ends)."""
    model = jaw.model
    jaw.goal_deg(model.jaw.limits_deg[0])
    t0 = time.perf_counter()
    first_error: dict[str, Any] | None = None
    status: dict[str, Any] = {}
    link = jaw.link
    alerts, link.raise_on_alert = link.raise_on_alert, False  # read the bits by name here
    try:
        while (t := time.perf_counter() - t0) < seconds:
            status = jaw.status()
            if status["errors"]:
                first_error = {"t_s": t, "errors": status["errors"]}
                jaw.relax()
                break
            time.sleep(0.05)
        position = jaw.position_deg()
        if first_error is None:
            jaw.goal_deg(model.jaw.open_deg)
    finally:
        link.raise_on_alert = alerts
    return {
        "seconds": seconds,
        "position_deg": position,
        "tripped": first_error is not None,
        "first_error": first_error,
        "last_status": status,
    }


def _check_plans(model: BusServoModel, hold: bool) -> GoalPlan:
    """The verification's plan, refused (ValueError) if it or the hold leaves the calibrated
    jaw's goal range."""
    import numpy as np

    from gripper_env.sysid.bus_experiments import GoalPlan, check_plan, tracking_plan

    assert model.calibration is not None
    plan = tracking_plan(model)
    goal_range = model.calibration.goal_range_deg()
    check_plan(plan, goal_range, "verification (the tuner's steps of 4 to 44 deg)")
    if hold:
        closed = GoalPlan(np.zeros(1), np.array([model.jaw.limits_deg[0]]), 1.0)
        check_plan(closed, goal_range, "hold (closing on the object)")
    return plan


def _parser() -> argparse.ArgumentParser:
    parser = BusArgumentParser(
        prog="python -m tuners.bus.deploy",
        description="Write tuned registers to a bus servo behind a gate (margins and hold on the "
        "model they were tuned on), read them back, run the verification steps and compare "
        "with the model's prediction; keep them with --save, else restore the servo as found.",
    )
    parser.add_argument(
        "--registers", required=True, metavar="FILE", help="registers file (tuners.bus.tune)"
    )
    add_servo_arguments(parser, model=False)
    parser.add_argument(
        "--jaw",
        default=None,
        metavar="FILE",
        help="the jaw calibration (python -m tuners.bus.calibrate), if the registers file's "
        "model carries none",
    )
    parser.add_argument(
        "--save",
        action="store_true",
        help="keep the registers after a verification without error: an STS3215's gains are "
        "saved to its flash (once); default: restore the servo as found",
    )
    parser.add_argument(
        "--hold",
        type=float,
        default=0.0,
        metavar="S",
        help="also close on the object in the jaws and hold S seconds, watching for an "
        "overload (default 0: no hold)",
    )
    parser.add_argument(
        "--allow-infeasible",
        action="store_true",
        help="write registers that miss the constraints (an unstable loop is always refused)",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default: next to the registers)"
    )
    parser.add_argument("--no-plot", action="store_true", help="skip response.png")
    return conform(parser, "tuners.bus.deploy")


def _run(args: argparse.Namespace) -> int:
    if not 0.0 <= args.hold <= 600.0:
        raise ValueError(f"--hold must be 0..600 s, got {args.hold}")
    from gripper_env.model.bus_servo import (
        alternative_models,
        load_registers_file,
        relative_uncertainties,
    )

    model, regs, doc = load_registers_file(args.registers)
    source = str(args.registers)
    rel_std = relative_uncertainties(doc, "uncertainty_rel_std", source)
    alternatives = alternative_models(doc, "alternative_models", source)
    calibration = load_jaw(args.jaw, model, args.id)
    top = calibration.servo.max_torque_limit if calibration.servo else None
    if top is not None and regs.torque_limit > top:
        raise ValueError(
            f"refusing to deploy {regs.label()}: its torque limit is above the servo's maximum "
            f"torque limit {top} (its own protection, read at calibration; tune on a model "
            "identified from records of this servo, which keeps within it)"
        )
    model = model.calibrated(calibration)
    alternatives = [m.calibrated(calibration) for m in alternatives]
    score = gate(model, regs, rel_std, args.allow_infeasible, alternatives)
    # the recorder after the files' checks: a refused file costs no identification imports
    from gripper_env.sysid.bus_experiments import BusRecorder
    from gripper_env.sysid.bus_servo import write_bus_record

    plan = _check_plans(model, args.hold > 0)
    out = output_folder(args.out or Path(args.registers).parent / f"deploy_{model.name}")
    hold = None
    saved: list[str] = []
    with open_gripper(args, model, calibration) as jaw:
        if jaw.model.protection != model.protection:  # the owner changed it since: judge again
            print(f"note: {_protection_change(model, jaw)}: the registers are judged again "
                  "under the servo's", flush=True)  # fmt: skip
            fresh = [a.with_updates(protection=jaw.model.protection) for a in alternatives]
            score = gate(jaw.model, regs, rel_std, args.allow_infeasible, fresh)
        written = jaw.write_registers(regs)
        if written != regs:
            raise BusError(f"registers read back as {written.label()}, not {regs.label()}")
        recorder = BusRecorder(jaw)
        rec = recorder.record(regs, plan)
        write_bus_record(out / "response.csv", rec)
        if args.hold > 0:
            hold = _hold(jaw, args.hold)
            if hold["tripped"]:
                _write_report(args, out, model, regs, written, score, rec, recorder, hold, [])
                bits = ", ".join(hold["first_error"]["errors"])
                raise BusAlertError(
                    f"servo {jaw.servo_id} TRIPPED during the hold: {bits} at "
                    f"{hold['first_error']['t_s']:.2f} s (report in {out / 'report.json'})",
                    jaw.servo_id,
                    hold["first_error"]["errors"],
                )
        if args.save:
            saved = jaw.save(regs)
    assert jaw.restored is not None
    restored = jaw.restored.describe()
    fit, gap = _write_report(args, out, model, regs, written, score, rec, recorder, hold, saved)
    m = score.robust_margins
    held = ""
    if hold is not None:
        held = f", hold {args.hold:g} s: no trip"
    kept = _kept(jaw, saved) if args.save else "a trial: the registers were restored as found"
    print(
        f"deployed {regs.label()} to servo {jaw.servo_id} on {args.port} (read back equal; "
        f"robust Ms {m.ms:.2f}, GM {m.gm_db:.1f} dB): fit {fit:.1f} % to the prediction, "
        f"largest end-of-step gap {gap:.2f} deg{held}; {jaw.link.retried} replies lost and "
        f"sent again -> {out}"
    )
    print(f"{kept}; {restored}")
    return 0


def _protection_change(model: BusServoModel, jaw: BusGripper) -> str:
    """What differs between the protection ``model`` was tuned under and the servo's own."""
    was = model.calibration.servo if model.calibration is not None else None
    changes = was.protection_changes(jaw.servo_registers) if was is not None else []
    if changes:
        return f"servo {jaw.servo_id}'s protection registers changed: {', '.join(changes)}"
    return (
        f"servo {jaw.servo_id}'s protection registers are not the {model.family} defaults the "
        "registers were tuned under"
    )


def _kept(jaw: BusGripper, saved: list[str]) -> str:
    if saved:
        return (
            f"saved {', '.join(saved)} to servo {jaw.servo_id}'s flash (once); the torque "
            "limit, acceleration and velocity are RAM registers, kept until power-off"
        )
    return (
        f"kept in servo {jaw.servo_id}'s RAM until power-off (the {jaw.model.family}'s position "
        "gains have no flash copy: write them at each start)"
    )


def _write_report(
    args: argparse.Namespace,
    out: Path,
    model: BusServoModel,
    regs: RegisterSet,
    written: RegisterSet,
    score: BusScore,
    rec: BusRecord,
    recorder: BusRecorder,
    hold: dict[str, Any] | None,
    saved: list[str],
) -> tuple[float, float]:
    """Write report.json (and response.png); the fit % and the largest end-of-step gap."""
    import numpy as np

    from gripper_env.evaluation.metrics import fit_percent
    from gripper_env.sysid.bus_servo import predict_record

    predicted = predict_record(model, rec)
    fit = float(fit_percent(rec.position_deg, predicted))
    steps = _step_errors(rec, predicted)
    gap = max(abs(s["measured_deg"] - s["predicted_deg"]) for s in steps)
    jaw: BusGripper = args.gripper
    report = {
        "registers": regs.model_dump(),
        "model": model.name,
        "family": model.family,
        "port": args.port,
        "id": args.id,
        "jaw": model.calibration.model_dump() if model.calibration else None,
        "read_back": written.model_dump(),
        "gate": score.as_dict(),
        "fit_pct": fit,
        "rms_error_deg": float(np.sqrt(np.mean((rec.position_deg - predicted) ** 2))),
        "steps": steps,
        "largest_step_gap_deg": gap,
        "readings": int(rec.t_s.size),
        "readings_lost": recorder.lost,
        "replies_retried": jaw.link.retried,
        "hold": hold,
        "saved": saved,
        "kept": bool(args.save) and not (hold is not None and hold["tripped"]),
        "registers_file": str(args.registers),
    }
    write_json(out / "report.json", report)
    if not args.no_plot:
        from tuners.bus.plots import plot_deploy

        plot_deploy(rec.t_s, rec.goal_deg, rec.position_deg, predicted,
                    f"{model.name}: {regs.label()} on {args.port}, fit {fit:.1f} %",
                    out / "response.png")  # fmt: skip
    return fit, gap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.deploy``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

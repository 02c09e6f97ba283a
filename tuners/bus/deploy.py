"""``python -m tuners.bus.deploy``: write tuned registers to a bus servo behind a gate, verify
them, and compare the servo's response with the model's prediction.

Recipe:

1. read the registers file of ``python -m tuners.bus.tune`` (the registers and the model they
   were tuned on, with its uncertainties);
2. **gate**: judge the registers on that model (:func:`gripper_env.evaluation.bus_servo.judge`:
   the loop's margins, free and on an object, over the model's uncertainty corners; the grasp and
   hold without a protection trip). Refuse (exit 2) registers that fail: an unstable loop always,
   the rest unless ``--allow-infeasible``;
3. write the registers with the torque off and read each back;
4. run the verification: the tuner's tracking steps (4 to 44 deg, both ways), the position read
   over the bus; with ``--hold S``, close on the object in the jaws and hold S seconds, watching
   the error bits for an overload;
5. simulate the same goal writes on the model (the prediction), and write ``response.csv`` (the
   record), ``report.json`` (fit % to the prediction, per-step errors, the hold) and
   ``response.png`` to ``--out``.

Examples
--------
``python -m tuners.bus.deploy --registers runs/bus/sts3215/my-sts3215_registers.json --port P``
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.evaluation.bus_servo import BusScore, judge
from gripper_env.evaluation.metrics import fit_percent
from gripper_env.hardware.bus.gripper import BusGripper
from gripper_env.io.files import write_json
from gripper_env.model.bus_servo import (
    BusServoModel,
    RegisterSet,
    alternative_models,
    load_registers_file,
)
from gripper_env.sysid.bus_experiments import BusRecorder, tracking_plan
from gripper_env.sysid.bus_servo import BusRecord, predict_record, write_bus_record
from tuners.bus.cli import add_servo_arguments, run_cli

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
    """Close on the object and hold ``seconds``: position, error bits and when they came."""
    model = jaw.model
    jaw.goal_deg(model.jaw.limits_deg[0])
    t0 = time.perf_counter()
    first_error: dict[str, Any] | None = None
    status: dict[str, Any] = {}
    while (t := time.perf_counter() - t0) < seconds:
        status = jaw.status()
        if status["errors"] and first_error is None:
            first_error = {"t_s": t, "errors": status["errors"]}
        time.sleep(0.05)
    position = jaw.position_deg()
    jaw.goal_deg(model.jaw.open_deg)
    return {
        "seconds": seconds,
        "position_deg": position,
        "tripped": first_error is not None,
        "first_error": first_error,
        "last_status": status,
    }


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.deploy",
        description="Write tuned registers to a bus servo behind a gate (margins and hold on the "
        "model they were tuned on), read them back, run the verification steps and compare "
        "with the model's prediction.",
    )
    parser.add_argument(
        "--registers", required=True, metavar="FILE", help="registers file (tuners.bus.tune)"
    )
    add_servo_arguments(parser, model=False)
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
    return parser


def _run(args: argparse.Namespace) -> int:
    if not 0.0 <= args.hold <= 600.0:
        raise ValueError(f"--hold must be 0..600 s, got {args.hold}")
    model, regs, doc = load_registers_file(args.registers)
    rel_std = doc.get("uncertainty_rel_std") or None
    alternatives = alternative_models(doc, "alternative_models", str(args.registers))
    score = gate(model, regs, rel_std, args.allow_infeasible, alternatives)
    out = args.out or Path(args.registers).parent / f"deploy_{model.name}"
    out.mkdir(parents=True, exist_ok=True)
    with BusGripper(args.port, model, args.id, baudrate=args.baudrate) as jaw:
        written = jaw.write_registers(regs)
        if written != regs:
            raise ValueError(f"registers read back as {written.label()}, not {regs.label()}")
        recorder = BusRecorder(jaw)
        rec = recorder.record(regs, tracking_plan(model))
        write_bus_record(out / "response.csv", rec)
        hold = _hold(jaw, args.hold) if args.hold > 0 else None
    predicted = predict_record(model, rec)
    fit = float(fit_percent(rec.position_deg, predicted))
    steps = _step_errors(rec, predicted)
    gap = max(abs(s["measured_deg"] - s["predicted_deg"]) for s in steps)
    report = {
        "registers": regs.model_dump(),
        "model": model.name,
        "family": model.family,
        "port": args.port,
        "id": args.id,
        "read_back": written.model_dump(),
        "gate": score.as_dict(),
        "fit_pct": fit,
        "rms_error_deg": float(np.sqrt(np.mean((rec.position_deg - predicted) ** 2))),
        "steps": steps,
        "largest_step_gap_deg": gap,
        "readings": int(rec.t_s.size),
        "replies_lost": recorder.lost,
        "hold": hold,
        "registers_file": str(args.registers),
    }
    write_json(out / "report.json", report)
    if not args.no_plot:
        from tuners.bus.plots import plot_deploy

        plot_deploy(rec.t_s, rec.goal_deg, rec.position_deg, predicted,
                    f"{model.name}: {regs.label()} on {args.port}, fit {fit:.1f} %",
                    out / "response.png")  # fmt: skip
    m = score.robust_margins
    held = ""
    if hold is not None:
        trip = f"TRIPPED {hold['first_error']}" if hold["tripped"] else "no trip"
        held = f", hold {args.hold:g} s: {trip}"
    print(
        f"deployed {regs.label()} to servo {args.id} on {args.port} (read back equal; robust Ms "
        f"{m.ms:.2f}, GM {m.gm_db:.1f} dB): fit {fit:.1f} % to the prediction, largest "
        f"end-of-step gap {gap:.2f} deg{held} -> {out}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.deploy``."""
    return run_cli(_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())

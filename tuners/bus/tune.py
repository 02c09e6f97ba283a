"""``python -m tuners.bus.tune``: search a bus servo's integer registers with Optuna.

The search space is the registers themselves, integers in the servo's units: P, I, D and the
torque limit (:data:`SEARCH_SPACE`, per family). Every candidate is judged on the model
(:func:`gripper_env.evaluation.bus_servo.judge`): the cost is tracking (IAE, overshoot, settled
error, chatter) plus the time to grasp; the constraints are the loop's margins (``Ms <= 1.6``,
gain margin >= 6 dB, on the model and its uncertainty corners) and the hold (grasp within 1 s,
hold 20 % of stall force for 10 s, no overload or thermal trip). The sampler is Optuna's
multivariate TPE with those constraints (``constraints_func``), started from the factory and
community registers (enqueued first). The result - the best feasible registers, the baselines
judged on the same terms, the margins - goes to a JSON file that ``python -m tuners.bus.deploy``
takes, with a figure of tracking and hold.

Examples
--------
``python -m tuners.bus.tune --model sts3215 --trials 300 --out results/bus``
``python -m tuners.bus.tune --model runs/bus/mine_model.json --out runs/bus``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import optuna

from gripper_env.evaluation.bus_servo import GM_MIN_DB, MS_MAX, BusScore, judge
from gripper_env.io.config import ConfigError
from gripper_env.io.files import write_atomic
from gripper_env.model.bus_servo import BusServoModel, RegisterSet, load_bus_servo

__all__ = ["SEARCH_SPACE", "constraint_value", "main", "tune_registers"]

#: Integer search ranges per family: (low, high) of P, I, D and the torque limit register. The
#: STS3215's gains are one-byte registers (0-254); the XL's position gains go to 16383, searched
#: here up to where the loop is long unstable. The torque limit's floor is 10 % (below it the
#: jaw does not overcome its friction reliably).
SEARCH_SPACE: dict[str, dict[str, tuple[int, int]]] = {
    "sts3215": {"p": (1, 254), "i": (0, 64), "d": (0, 254), "torque_limit": (100, 1000)},
    "xl330": {"p": (10, 6000), "i": (0, 4000), "d": (0, 12000), "torque_limit": (90, 885)},
    "xl430": {"p": (10, 6000), "i": (0, 4000), "d": (0, 12000), "torque_limit": (90, 885)},
}


def constraint_value(score: BusScore) -> float:
    """How far ``score`` is from feasible (0 when feasible): the sum of the scaled excesses."""
    if score.feasible:
        return 0.0
    m, h = score.robust_margins, score.hold
    v = 0.0
    if not m.stable:
        v += 10.0
    else:
        v += max(m.ms - MS_MAX, 0.0) + max(GM_MIN_DB - m.gm_db, 0.0) / GM_MIN_DB
    if h.overload:
        v += 1.0 + max(10.0 - (h.trip_at_s or 0.0), 0.0) / 10.0
    else:
        v += max(h.required_force_n - h.min_force_n, 0.0) / max(h.required_force_n, 1e-9)
        t = h.time_to_grasp_s if math.isfinite(h.time_to_grasp_s) else 10.0
        v += max(t - 1.0, 0.0)
    return max(v, 1e-6)


def tune_registers(
    model: BusServoModel,
    *,
    trials: int = 300,
    seed: int = 0,
    rel_std: dict[str, float] | None = None,
    progress: bool = True,
) -> tuple[BusScore, optuna.Study]:
    """The best feasible registers for ``model`` found in ``trials`` Optuna trials.

    Raises
    ------
    RuntimeError
        If no trial is feasible (the constraints cannot be met on this model).
    """
    space = SEARCH_SPACE[model.family]
    base = model.factory

    def objective(trial: optuna.Trial) -> float:
        values = {k: trial.suggest_int(k, lo, hi) for k, (lo, hi) in space.items()}
        regs = base.model_copy(update=values)
        score = judge(model, [regs], rel_std=rel_std)[0]
        trial.set_user_attr("constraint", constraint_value(score))
        trial.set_user_attr("score", score.as_dict())
        return score.cost

    sampler = optuna.samplers.TPESampler(
        seed=seed,
        multivariate=True,
        n_startup_trials=min(20, max(trials // 5, 1)),
        constraints_func=lambda t: (t.user_attrs.get("constraint", 1.0),),
    )
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    for regs in model.baselines().values():
        clipped = {k: min(max(getattr(regs, k), lo), hi) for k, (lo, hi) in space.items()}
        study.enqueue_trial(clipped, skip_if_exists=True)
    study.optimize(objective, n_trials=trials, show_progress_bar=progress)
    feasible = [t for t in study.trials if t.user_attrs.get("constraint", 1.0) <= 0.0]
    if not feasible:
        raise RuntimeError(
            f"no feasible registers in {trials} trials on {model.name}: every candidate broke "
            "the margins or the hold (try more --trials, or check the model)"
        )
    best = min(feasible, key=lambda t: math.inf if t.value is None else float(t.value))
    regs = base.model_copy(update={k: best.params[k] for k in space})
    return judge(model, [regs], rel_std=rel_std)[0], study


def _on_bounds(regs: RegisterSet, family: str) -> list[str]:
    out = []
    for k, (lo, hi) in SEARCH_SPACE[family].items():
        v = getattr(regs, k)
        if v in (lo, hi) and not (k == "i" and v == 0):
            out.append(f"{k}={v} on its search bound [{lo}, {hi}]")
    return out


def format_table(rows: dict[str, BusScore]) -> str:
    """A markdown table of judged register sets (tracking, hold, margins)."""
    lines = [
        "| registers | cost | IAE (deg s) | IAE/step (s) | overshoot (deg) | settled error (deg) "
        "| chatter (1/s) "
        "| grasp (s) | hold force (N) | least force (N) | trip | Ms | GM (dB) | PM (deg) "
        "| robust Ms / GM | feasible |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in rows.items():
        t, h, m, r = s.tracking, s.hold, s.margins, s.robust_margins
        trip = "none" if not h.overload else f"{h.trip} at {h.trip_at_s:.2f} s"
        lines.append(
            f"| {name}: {s.registers.label()} | {s.cost:.2f} | {t.iae:.2f} | {t.iae_per_deg_s:.3f} "
            f"| {t.overshoot_deg:.2f} "
            f"| {t.settled_error_deg:.2f} | {t.chatter:.1f} | {h.time_to_grasp_s:.2f} "
            f"| {h.holding_force_n:.1f} | {h.min_force_n:.1f} | {trip} | {m.ms:.2f} "
            f"| {m.gm_db:.1f} | {m.pm_deg:.0f} | {r.ms:.2f} / {r.gm_db:.1f} "
            f"| {'yes' if s.feasible else 'no: ' + '; '.join(s.violations)} |"
        )
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.tune",
        description="Search a bus servo's P, I, D and torque-limit registers (integers) with "
        "Optuna on its model, under the loop's margins and a grasp-and-hold constraint.",
    )
    parser.add_argument(
        "--model",
        default="sts3215",
        help="a shipped model (sts3215, xl330, xl430) or an identified model file "
        "(python -m tuners.bus.identify --out); default sts3215",
    )
    parser.add_argument("--trials", type=int, default=300, help="Optuna trials (default 300)")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bus"), help="folder for <name>_registers.json/.md"
    )
    parser.add_argument("--no-plot", action="store_true", help="do not draw the figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not 1 <= args.trials <= 100_000:
        print(f"error: --trials must be 1..100000, got {args.trials}", file=sys.stderr)
        return 2
    try:
        model = load_bus_servo(args.model)
    except ConfigError as exc:
        print(f"error: --model: {exc}", file=sys.stderr)
        return 2
    rel_std = _model_uncertainty(args.model)
    try:
        best, _study = tune_registers(
            model, trials=args.trials, seed=args.seed, rel_std=rel_std,
            progress=not args.no_progress and sys.stderr.isatty(),
        )  # fmt: skip
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    baselines = dict(zip(model.baselines(), judge(model, list(model.baselines().values()),
                                                   rel_std=rel_std), strict=False))  # fmt: skip
    rows = {"tuned": best, **baselines}
    table = format_table(rows)
    bounds = _on_bounds(best.registers, model.family)
    print(f"{model.name} ({model.family}), {args.trials} trials, seed {args.seed}")
    print(table)
    for note in bounds:
        print(f"note: {note}")
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{model.name}_registers"
    doc = {
        "family": model.family,
        "name": model.name,
        "registers": best.registers.model_dump(),
        "score": best.as_dict(),
        "baselines": {k: v.as_dict() for k, v in baselines.items()},
        "search_space": SEARCH_SPACE[model.family],
        "trials": args.trials,
        "seed": args.seed,
        "uncertainty_rel_std": rel_std or {},
        "on_bounds": bounds,
        "model": model.model_dump(),
    }
    write_atomic(stem.with_suffix(".json"), json.dumps(doc, indent=2) + "\n")
    write_atomic(stem.with_suffix(".md"), f"# {model.name}: tuned registers\n\n{table}\n")
    if not args.no_plot:
        from tuners.bus.plots import plot_registers

        plot_registers(model, rows, stem.with_suffix(".png"))
    print(f"wrote {stem.with_suffix('.json')}")
    return 0


def _model_uncertainty(model_arg: str) -> dict[str, float] | None:
    """Relative standard errors from an identified model file (``"uncertainty"`` key)."""
    if not str(model_arg).endswith(".json"):
        return None
    try:
        doc = json.loads(Path(model_arg).read_text())
    except (OSError, ValueError):
        return None
    unc = doc.get("uncertainty", {}) if isinstance(doc, dict) else {}
    return {k: float(v) for k, v in unc.items() if isinstance(v, int | float)} or None


if __name__ == "__main__":
    raise SystemExit(main())

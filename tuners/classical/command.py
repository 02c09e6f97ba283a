"""``python -m tuners.classical``: PID gains by a textbook robust design, at its best or fixed."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from tuners import cli

__all__ = ["METHOD_NAMES", "build_parser", "main"]

#: The rules ``--method`` takes (:data:`tuners.classical.rules.METHODS`, checked by a test): the
#: rules themselves load after the command line is checked (tuners.conventions).
METHOD_NAMES = ("simc", "lambda", "amigo-pi", "amigo-pid", "migo", "pidtune")


def build_parser():
    parser = cli.base_parser(
        "tuners.classical",
        "PID gains from the plant's model by a textbook robust design, its robustness knob set "
        "to the best value that meets the objective's constraints (or, with --fixed, at the "
        "rule's fixed setting from the config).",
    )
    parser.add_argument(
        "--method",
        choices=(*METHOD_NAMES, "all"),
        default=None,
        help="design method (default: the config's 'method'); 'all' runs every one",
    )
    parser.add_argument(
        "--fixed",
        action="store_true",
        help="the rule at the config's fixed knob setting (e.g. SIMC's tau_c = theta), as a "
        "reference; written as classical-<method>-fixed",
    )
    parser.add_argument(
        "--plants",
        default=None,
        help="robust: the knob must meet the constraints on every one of these plants (e.g. "
        "test2,test3,test4) at the least mean cost; the rule reads --plant's model",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="method settings; default configs/tuners/classical.yaml",
    )
    parser.add_argument(
        "--optuna-config",
        type=Path,
        default=None,
        help="where the tuning seeds come from; default configs/tuners/optuna.yaml",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m tuners.classical`` and ``gripper-classical``."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    from tuners.settings import ClassicalSettings, OptunaSettings, check_disjoint, load_settings

    # the inputs are checked before the rules' imports (python-control, scipy.signal): a
    # refusal costs a second, not the tuning stack's
    inputs = cli.resolve(args)
    settings = load_settings(ClassicalSettings, args.config)
    opt = load_settings(OptunaSettings, args.optuna_config)
    check_disjoint(opt.tuning_seeds, inputs.settings.seeds)
    plants = cli.plants_arg(args.plants)
    from tuners.classical.constrained import KNOBS
    from tuners.classical.rules import require_stable
    from tuners.classical.tuner import tune_rule, tuner_name

    require_stable(inputs.plant)  # refused before any work (and any progress line)
    chosen = args.method or settings.method
    methods = list(METHOD_NAMES) if chosen == "all" else [chosen]
    if args.json and len(methods) > 1:
        raise ValueError("--json prints one gains file; use it with one --method, not 'all'")
    for method in methods:
        start = time.perf_counter()
        where = "+".join(plants) or inputs.plant.name
        how = (
            "its knob set under the constraints"
            if method in KNOBS and not args.fixed
            else ("at its fixed setting")
        )
        print(f"{method} on {where}: FOPDT fit, then the rule with {how} "
              f"(scored on the tuning seeds)...", file=sys.stderr, flush=True)  # fmt: skip
        gains, tuning = tune_rule(
            method, inputs, settings, fixed=args.fixed, plants=plants, optuna_settings=opt
        )
        fopdt = tuning["fopdt"]
        notes = [
            f"{method}: FOPDT k={fopdt['k']:.4g} tau={fopdt['tau_s']:.4g} s "
            f"theta={fopdt['theta_s']:.4g} s"
        ]
        if "knob" in tuning:
            k = tuning["knob"]
            notes.append(
                f"{method}: {k['name']} = {k['value']:.4g} ({k['meaning']}), the best setting in "
                f"[{k['range'][0]:g}, {k['range'][1]:g}] that meets the constraints "
                f"(tuning cost {tuning['best_value_tuning']:.4g})"
            )
        print(
            f"{method}: evaluating P={gains.P:.4g} I={gains.I:.4g} D={gains.D:.4g} on "
            f"{inputs.settings.seeds.count} held-out seeds...",
            file=sys.stderr,
            flush=True,
        )
        cli.publish(
            args,
            inputs,
            tuner=tuner_name(method, args.fixed or method not in KNOBS, bool(plants)),
            gains=gains,
            sign=1,
            label=method,
            tuning=tuning,
            budget_episodes=int(tuning.get("episodes", 0)),
            config={"classical": settings.model_dump()},
            wall_time_s=time.perf_counter() - start,
            notes=notes,
        )
    return 0

"""Tune PID gains with Optuna through the tuner API, and compare them with the paper's.

The command ``python -m tuners.optuna --plant test2`` does the same with a journal file, several
search seeds and a written report; this script calls the pieces it is built from:

1. the inputs every tuner takes (:class:`tuners.cli.Inputs`: plant, actual-gripper preset,
   reference profile, evaluation settings with the held-out disturbance seeds, objective);
2. :class:`tuners.optuna.tuner.OptunaTuner`, the benchmark's Optuna row: one in-memory TPE
   search under the robustness constraints (Ms and gain margin of the loop as it runs, with the
   servo's 20 ms command hold);
3. :func:`tuners.cli.make_result`: the gains evaluated on the ideal model and on the actual
   gripper over the held-out seeds, their margins, and the same gains on the gripper's other
   identifications, as the gains file every tuner writes.

Run::

    python examples/tune_optuna.py                  # 64 trials on test2, a few seconds
    python examples/tune_optuna.py --trials 200 --out my-results   # also write the gains file

With ``--out DIR`` it writes ``DIR/<plant>/optuna.json`` (and the response plot), the file
``examples/deploy_virtual.py --gains`` and ``python -m tuners.rig.deploy`` take.
"""

from __future__ import annotations

import argparse
import time

from tuners import cli
from tuners.interface import Budget
from tuners.manual import PAPER_GAINS
from tuners.optuna.tuner import OptunaTuner
from tuners.settings import EvaluationSettings, SeedRange


def make_inputs(plant_name: str, eval_seeds: int) -> cli.Inputs:
    """What every tuner is given: the plant, the ``actual`` preset, the paper's step profile,
    and ``eval_seeds`` held-out disturbance seeds (disjoint from Optuna's tuning seeds)."""
    settings = EvaluationSettings(seeds=SeedRange(start=100_000, count=eval_seeds))
    return cli.load_inputs(plant_name, "actual", "step", settings=settings)


def margins(robustness: dict) -> str:
    """One line of the margins of the loop as it runs (servo command held 20 ms)."""
    gm = robustness["gain_margin_db"]
    return (
        f"GM {'inf' if gm is None else f'{gm:.1f}'} dB, PM {robustness['phase_margin_deg']:.1f} "
        f"deg, Ms {robustness['ms']:.2f} "
        f"(constraints Ms <= {robustness['constraints']['ms_max']:g}, "
        f"GM >= {robustness['constraints']['gm_min_db']:g} dB: "
        f"{'met' if robustness['meets_constraints'] else 'NOT met'})"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plant", default="test2", help="plant to tune on (default: test2)")
    parser.add_argument("--trials", type=int, default=64, help="Optuna trials (default: 64)")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default: 0)")
    parser.add_argument(
        "--eval-seeds", type=int, default=10, help="held-out disturbance seeds (default: 10)"
    )
    parser.add_argument(
        "--out", default=None, help="also write the gains file OUT/<plant>/optuna.json"
    )
    args = parser.parse_args(argv)

    inputs = make_inputs(args.plant, args.eval_seeds)
    tuner = OptunaTuner("tpe", trials=args.trials, search_seeds=1)
    start = time.perf_counter()
    tuned = tuner.tune(inputs, Budget(), seed=args.seed)
    wall = time.perf_counter() - start
    assert tuned.gains is not None
    g = tuned.gains
    print(
        f"{inputs.plant.name}: {args.trials} Optuna trials, {tuned.episodes} simulated "
        f"episodes, {wall:.1f} s"
    )
    print(f"gains: P={g.P:.4g} I={g.I:.4g} D={g.D:.4g} N={g.N:g}")

    # The gains file's content: evaluation on held-out seeds, margins, other identifications.
    content, evaluation = cli.make_result(
        inputs, tuner=tuner.name, gains=g, tuning=tuned.tuning, label=tuned.label,
        seed=args.seed, wall_time_s=wall, budget_episodes=tuned.episodes,
    )  # fmt: skip
    paper = PAPER_GAINS["paper-tuned"]
    paper_content, _ = cli.make_result(
        inputs, tuner="manual", gains=paper.gains, sign=paper.sign, label=paper.label
    )
    cost = content["metrics"]["actual"]["mean"]["cost"]
    paper_cost = paper_content["metrics"]["actual"]["mean"]["cost"]
    print(
        f"cost on the actual gripper, mean over {args.eval_seeds} held-out seeds: {cost:.2f} "
        f"(the paper's tuned gains: {paper_cost:.2f})"
    )
    print(f"margins with the servo's 20 ms hold: {margins(content['robustness'])}")
    cross = content.get("cross_model") or {}
    if cross:  # only for the paper's plants: the same gains on the gripper's other fits
        unstable = [name for name, row in cross["plants"].items() if not row["stable"]]
        print(
            f"on the other identifications ({', '.join(cross['plants'])}): worst Ms "
            f"{cross['worst']['ms']:.2f} (over {', '.join(cross['worst']['over'])}), unstable on "
            f"{', '.join(unstable) or 'none'}"
        )
    if args.out is not None:
        path = cli.write_result(args.out, inputs, content, evaluation, force=True)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The benchmark: every tuner on every plant, on the ideal and on the actual-gripper model.

Usage::

    python -m tuners.benchmark                  # full run (configs/benchmark.yaml)
    python -m tuners.benchmark --quick          # small budgets, a few minutes

For every plant and tuner (the paper's gains, classical rules, Optuna with TPE, CMA-ES and random
sampling under one budget of simulated episodes, and the RL tuner when the environments are
installed) it records the gains, the nominal closed-loop stability, the paper's metrics
(overshoot on grip and un-grip, SD, SD gap) and IAE, settling time, control effort and cost on
the ``ideal`` model and on the ``actual`` model (mean and 95 % confidence interval over the
held-out seeds), the sim-to-real gap, the best tuning cost against the episodes used, and the
wall time. Writes ``<out>/benchmark.md``, ``<out>/benchmark.json``, the figures
``<out>/figures/benchmark_*.png`` and each tuner's gains file ``<out>/<plant>/<tuner>.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.config import CONFIG_DIR, load_yaml, validate
from gripper_env.disturbances import load_disturbance
from gripper_env.plants import load_plant
from gripper_env.references import load_reference
from tuners import classical, cli, manual
from tuners import optuna as optuna_tuner
from tuners.gains_file import provenance, write_atomic, write_json
from tuners.plotting import budget_plot, save_figure
from tuners.settings import (
    ClassicalSettings,
    EvaluationSettings,
    OptunaSettings,
    check_disjoint,
    load_settings,
)

__all__ = ["BenchmarkSettings", "main", "run_benchmark"]


class _OptunaPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    samplers: list[str] = ["tpe", "cmaes", "random"]
    trials: int = Field(200, ge=1)


class _RLPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    enabled: bool = True
    algo: str = "ppo"
    timesteps: int = Field(800, ge=1)


class _QuickPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    optuna_trials: int = Field(32, ge=1)
    rl_timesteps: int = Field(128, ge=1)


class BenchmarkSettings(BaseModel):
    """``configs/benchmark.yaml`` (see the comments there)."""

    model_config = ConfigDict(extra="forbid")
    plants: list[str] = ["test1", "test2", "test3", "test4"]
    disturbance: str = "actual"
    profile: str = "step"
    seed: int = 0
    manual: list[str] = ["paper-untuned", "paper-tuned", "paper-hw-tuned"]
    classical: list[str] = ["simc", "lambda"]
    optuna: _OptunaPart = _OptunaPart()
    rl: _RLPart = _RLPart()
    quick: _QuickPart = _QuickPart()


def _inputs(plant: str, bench: BenchmarkSettings, ev: EvaluationSettings) -> cli.Inputs:
    p = load_plant(plant)
    return cli.Inputs(
        p,
        load_disturbance(bench.disturbance),
        load_reference(bench.profile, p.dt_s),
        ev,
        bench.disturbance,
        bench.profile,
    )


def _summary(content: dict[str, Any], wall_s: float, extra: dict[str, Any]) -> dict[str, Any]:
    return {
        "P": content["P"],
        "I": content["I"],
        "D": content["D"],
        "N": content["N"],
        "sign": content["sign"],
        "stability": content["stability"],
        "metrics": content["metrics"],
        "wall_time_s": wall_s,
        **extra,
    }


def run_benchmark(
    bench: BenchmarkSettings,
    ev: EvaluationSettings,
    optuna_settings: OptunaSettings,
    classical_settings: ClassicalSettings,
    out: Path,
    quick: bool = False,
    log=print,
    command: str | None = None,
) -> dict[str, Any]:
    """Run every tuner on every plant; write gains files and return the benchmark's data."""
    trials = bench.quick.optuna_trials if quick else bench.optuna.trials
    rl_steps = bench.quick.rl_timesteps if quick else bench.rl.timesteps
    per_trial = optuna_settings.tuning_seeds.count
    data: dict[str, Any] = {"plants": {}, "budget_episodes": trials * per_trial}
    rl_note = None
    rl_module = None
    if bench.rl.enabled:
        try:
            from tuners import rl as rl_module  # needs gripper_env.envs and stable-baselines3
        except ImportError as exc:
            rl_note = (
                "RL tuner not run: it needs the Gymnasium environments (gripper_env.envs) and "
                f"stable-baselines3 ({exc})"
            )
    else:
        rl_note = "RL tuner disabled in the benchmark config"
    for plant in bench.plants:
        inputs = _inputs(plant, bench, ev)
        rows: dict[str, Any] = {}
        curves: dict[str, list[tuple[int, float]]] = {}

        def record(tuner, gains, sign, wall, extra=None, *, label="", inputs=inputs, rows=rows):
            content, evaluation = cli.make_result(
                inputs,
                tuner=tuner,
                gains=gains,
                sign=sign,
                label=label,
                seed=bench.seed,
                tuning=extra,
                wall_time_s=wall,
                command=command,
            )
            cli.write_result(out, inputs, content, evaluation)
            rows[tuner] = _summary(content, wall, {"tuning": extra or {}})
            cost = content["metrics"]["actual"]["mean"]["cost"]
            shown = "inf" if cost is None else f"{cost:.4g}"
            log(f"  {inputs.plant.name:6s} {tuner:22s} actual cost {shown}")

        for preset in bench.manual:
            chosen = manual.PAPER_GAINS[preset]
            record(f"manual-{preset}", chosen.gains, chosen.sign, 0.0, label=preset)
        for rule in bench.classical:
            t0 = time.perf_counter()
            s = classical_settings.model_copy(update={"rule": rule})
            model = classical.fit_fopdt(inputs.plant, inputs.disturbance, s)
            gains, tau_c = classical.tune(model, s, ev.pid.N)
            wall = time.perf_counter() - t0
            name = "classical" if rule == "simc" else f"classical-{rule}"
            record(name, gains, 1, wall, {"rule": rule, "tau_c_s": tau_c, "fopdt": model.__dict__})
        for sampler in bench.optuna.samplers:
            t0 = time.perf_counter()
            result, scorer = optuna_tuner.search(
                inputs, optuna_settings, n_trials=trials, sampler_name=sampler, seed=bench.seed
            )
            wall = time.perf_counter() - t0
            name = optuna_tuner.tuner_name(sampler, False)
            curves[name] = result.history
            record(
                name,
                result.gains,
                1,
                wall,
                {
                    "sampler": sampler,
                    "trials": result.n_complete,
                    "episodes": scorer.episodes,
                    "best_value_tuning": result.best_value,
                    "history": result.history,
                },
            )
        if rl_module is not None:
            t0 = time.perf_counter()
            rl_result = rl_module.benchmark_tune(
                inputs, timesteps=rl_steps, seed=bench.seed, algo=bench.rl.algo, out=out
            )
            wall = time.perf_counter() - t0
            curves["rl-budget"] = rl_result["history"]
            record(
                "rl-budget",
                rl_result["gains"],
                1,
                wall,
                {k: v for k, v in rl_result.items() if k != "gains"},
            )
        fig = budget_plot(
            curves,
            f"{plant}: best tuning cost vs simulated episodes (same budget)",
            out / "figures" / f"benchmark_budget_{plant}.png",
        )
        data["plants"][plant] = {"tuners": rows, "budget_figure": str(fig.relative_to(out))}
    data["rl_note"] = rl_note
    return data


# ----------------------------------------------------------------------------------------------
# Report


def _f(x: Any, digits: int = 3) -> str:
    if x is None:
        return "never"
    if isinstance(x, bool):
        return "yes" if x else "no"
    return f"{x:.{digits}g}"


def _ci(actual: dict[str, Any], *path: str) -> str:
    def get(d):
        for k in path:
            d = d[k]
        return d

    mean, lo, hi = get(actual["mean"]), get(actual["ci95_low"]), get(actual["ci95_high"])
    if mean is None:
        return "never"
    if lo is None or hi is None or hi - lo < 1e-12:
        return _f(mean)
    return f"{_f(mean)} [{_f(lo)}, {_f(hi)}]"


def render_markdown(data: dict[str, Any], meta: dict[str, Any]) -> str:
    """The benchmark report (Markdown)."""
    lines = [
        "# Benchmark: PID tuners for the hobby-servo gripper",
        "",
        f"Generated by `{meta['command']}` ({meta['date']}, version {meta['version']}, commit "
        f"`{(meta.get('git_commit') or 'unknown')[:10]}`), total wall time "
        f"{meta['wall_time_s']:.0f} s. Profile `{meta['profile']}` (grip step 92 -> 21 deg at "
        f"1 s, un-grip at 10 s, 20 s), actual-gripper preset `{meta['disturbance']}`.",
        "",
        "* **ideal**: the identified transfer function alone (the paper's model), PID without "
        "output limits; **actual**: the actual-gripper model, PID output clamped to the servo "
        f"range, {meta['n_seeds']} held-out disturbance seeds (friction and sensor noise drawn "
        "per seed), mean and 95 % confidence interval of the mean (Student t).",
        "* Metrics score the true jaw angle. Overshoot on the actual model is 0 whenever the "
        "jaw hits its mechanical stops (21 and 92 deg are the stops): the stops hide overshoot "
        "that the ideal model shows.",
        "* cost: the shared objective (`configs/objective.yaml`); searches used "
        f"{meta['budget_episodes']} simulated episodes each ({meta['tuning_seeds']} tuning seeds "
        "per trial, disjoint from the held-out seeds).",
        "* nominal: the linear closed loop on the plant's model is stable (all poles inside the "
        "unit circle, `gripper_env.stability`).",
    ]
    if data.get("rl_note"):
        lines += [f"* {data['rl_note']}"]
    for plant, pdata in data["plants"].items():
        rows = pdata["tuners"]
        lines += [
            "",
            f"## {plant}",
            "",
            "| tuner | P | I | D | e | nominal | wall s |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, r in rows.items():
            lines.append(
                f"| {name} | {r['P']:.4g} | {r['I']:.4g} | {r['D']:.3g} | "
                f"{'r-y' if r['sign'] == 1 else 'y-r'} | {_f(r['stability']['stable'])} | "
                f"{r['wall_time_s']:.2f} |"
            )
        lines += [
            "",
            "Ideal model (the paper's TF):",
            "",
            "| tuner | grip OS % | un-grip OS % | SD deg | SD gap deg | IAE | settle s (grip) "
            "| effort deg | cost |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for name, r in rows.items():
            m = r["metrics"]["ideal"]
            lines.append(
                f"| {name} | {_f(m['grip']['overshoot_pct'])} | "
                f"{_f(m['ungrip']['overshoot_pct'])} | {_f(m['sd_deg'], 5)} | "
                f"{_f(m['sd_gap_deg'])} | {_f(m['iae'])} | {_f(m['grip']['settling_time_s'])} | "
                f"{_f(m['control_effort'])} | {_f(m['cost'])} |"
            )
        lines += [
            "",
            f"Actual model (mean [95 % CI] over {meta['n_seeds']} held-out seeds) and the "
            "sim-to-real gap (actual - ideal):",
            "",
            "| tuner | grip OS % | un-grip OS % | SD deg | SD gap deg | IAE | settle s (grip) "
            "| effort deg | cost | stable runs | gap: IAE | gap: cost |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for name, r in rows.items():
            a = r["metrics"]["actual"]
            gap = r["metrics"]["sim_to_real_gap"]
            lines.append(
                f"| {name} | {_ci(a, 'grip', 'overshoot_pct')} | "
                f"{_ci(a, 'ungrip', 'overshoot_pct')} | {_f(a['mean']['sd_deg'], 5)} | "
                f"{_ci(a, 'sd_gap_deg')} | {_ci(a, 'iae')} | "
                f"{_ci(a, 'grip', 'settling_time_s')} | {_ci(a, 'control_effort')} | "
                f"{_ci(a, 'cost')} | {a['stable_fraction'] * 100:.0f} % | {_f(gap['iae'])} | "
                f"{_f(gap['cost'])} |"
            )
        budget = [(n, r["tuning"]) for n, r in rows.items() if r["tuning"].get("history")]
        if budget:
            lines += [
                "",
                f"Budget-matched search (best cost on the tuning seeds after N episodes; "
                f"![figure]({pdata['budget_figure']})):",
                "",
                "| tuner | " + " | ".join(f"{n} ep" for n in _checkpoints(meta)) + " |",
                "|---|" + "---|" * len(_checkpoints(meta)),
            ]
            for name, tuning in budget:
                cells = [_f(_best_at(tuning["history"], n)) for n in _checkpoints(meta)]
                lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Figures: `figures/benchmark_cost.png` (actual-model cost per tuner and plant),",
        "`figures/benchmark_budget_<plant>.png`, and each tuner's response plot",
        "`<plant>/<tuner>.png` (reference, model and actual-model responses).",
        "",
    ]
    return "\n".join(lines)


def _checkpoints(meta: dict[str, Any]) -> list[int]:
    total, per_trial = meta["budget_episodes"], meta["tuning_seeds"]
    return sorted(
        {max(per_trial, per_trial * round(total * f / per_trial)) for f in (0.1, 0.25, 0.5, 1.0)}
    )


def _best_at(history: list, episodes: int) -> float | None:
    best = None
    for ep, value in history:
        if ep <= episodes:
            best = value
    return best


def cost_figure(data: dict[str, Any], path: Path) -> Path:
    """Grouped bars: actual-model cost (mean, 95 % CI) per tuner, one group per plant."""
    plants = list(data["plants"])
    tuners = list(dict.fromkeys(t for p in plants for t in data["plants"][p]["tuners"]))
    fig, ax = plt.subplots(figsize=(11, 4.5))
    width = 0.8 / max(1, len(tuners))
    for j, tuner in enumerate(tuners):
        xs, ys, errs = [], [], []
        for i, plant in enumerate(plants):
            row = data["plants"][plant]["tuners"].get(tuner)
            if row is None:
                continue
            a = row["metrics"]["actual"]
            mean, hi = a["mean"]["cost"], a["ci95_high"]["cost"]
            xs.append(i + (j - len(tuners) / 2 + 0.5) * width)
            ys.append(mean if mean is not None else math.nan)
            errs.append((hi - mean) if mean is not None and hi is not None else 0.0)
        ax.bar(xs, ys, width, yerr=errs, label=tuner, capsize=2)
    ax.set_xticks(range(len(plants)), plants)
    ax.set_yscale("log")
    ax.set_ylabel("cost on the actual model (held-out seeds)")
    ax.set_title("Benchmark: lower is better", fontsize=10)
    ax.legend(fontsize=7, ncol=4)
    ax.grid(alpha=0.3, axis="y", which="both")
    return save_figure(fig, path)


# ----------------------------------------------------------------------------------------------
# Command line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.benchmark",
        description="Run every tuner on every plant and compare them on the ideal and actual "
        "models.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--config", type=Path, default=CONFIG_DIR / "benchmark.yaml", help="benchmark settings"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small search budgets (a few minutes); what the test runs",
    )
    parser.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    parser.add_argument(
        "--eval-config",
        type=Path,
        default=None,
        help="evaluation settings; default configs/tuners/evaluation.yaml",
    )
    parser.add_argument(
        "--optuna-config",
        type=Path,
        default=None,
        help="Optuna settings; default configs/tuners/optuna.yaml",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print benchmark.json's content instead of progress lines",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    bench = validate(BenchmarkSettings, load_yaml(args.config), str(args.config))
    ev = load_settings(EvaluationSettings, args.eval_config)
    opt = load_settings(OptunaSettings, args.optuna_config)
    cls = load_settings(ClassicalSettings)
    check_disjoint(opt.tuning_seeds, ev.seeds)
    if ev.seeds.count < 10:
        raise ValueError(f"the benchmark needs at least 10 held-out seeds, got {ev.seeds.count}")
    for plant in bench.plants:
        load_plant(plant)
    load_disturbance(bench.disturbance)
    load_reference(bench.profile)
    for preset in bench.manual:
        if preset not in manual.PAPER_GAINS:
            raise ValueError(f"{args.config}: unknown manual preset {preset!r}")
    for sampler in bench.optuna.samplers:
        optuna_tuner.make_sampler(sampler, 0, opt, False)
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    data = run_benchmark(
        bench, ev, opt, cls, args.out, quick=args.quick, log=log, command=args.command
    )
    wall = time.perf_counter() - start
    meta = provenance(
        config={"benchmark": bench.model_dump(), "quick": args.quick},
        seed=bench.seed,
        wall_time_s=wall,
        command=args.command,
    )
    meta.update(
        profile=bench.profile,
        disturbance=bench.disturbance,
        n_seeds=ev.seeds.count,
        budget_episodes=data["budget_episodes"],
        tuning_seeds=opt.tuning_seeds.count,
    )
    cost_figure(data, args.out / "figures" / "benchmark_cost.png")
    content = {"provenance": meta, **data}
    write_json(args.out / "benchmark.json", content)
    write_atomic(args.out / "benchmark.md", render_markdown(data, meta))
    if args.json:
        print(json.dumps(json.loads((args.out / "benchmark.json").read_text()), indent=2))
    else:
        print(
            f"wrote {args.out / 'benchmark.md'} and {args.out / 'benchmark.json'} in {wall:.0f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))

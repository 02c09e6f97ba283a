"""The benchmark: every way of choosing gains, on every plant, judged as a control engineer would.

Usage::

    python -m tuners.benchmark                  # full run (configs/benchmark.yaml), ~15 min
    python -m tuners.benchmark --quick          # small budgets, a few minutes (the test's)

For every plant whose reference can be followed at all (:func:`gripper_env.scoring.reachability`;
test1 cannot follow the step profile within the servo's range and is reported as infeasible,
with the bang-bang bound, never ranked):

* **baselines**: the paper's gains (``manual-*``), ``command = reference`` (no feedback, the
  servo's own loop only), and the textbook robust designs (``classical-*``: SIMC, AMIGO PI/PID,
  MIGO, pidtune-like PM 60);
* **searches** under one budget of simulated episodes each: Optuna with TPE, CMA-ES and random
  sampling, ``search_seeds`` independent seeds each (the best kept, the spread reported), and the
  RL tuner (PPO on ``GripperPIDTune-v0``) over as many seeds;
* **robust** tuners, tuned once on several identifications (``robust.plants``) and evaluated on
  each: ``optuna-robust`` and the plant-conditioned RL tuner ``rl-conditioned``.

Every row is evaluated through the one scoring path on held-out seeds (:mod:`tuners.evaluation`):
actual-model IAE, visible overshoot, stall, the loop's margins and ``Ms`` with the servo's
command hold, the worst case on the other identifications, and the grip-onto-an-object scenario
(stall, force proxy, release delay). :mod:`tuners.leaderboard` ranks the rows that are stable
and meet the robustness constraints, tests the differences for significance (paired over the
held-out seeds) and writes ``<out>/benchmark.md``; ``<out>/benchmark.json`` holds everything,
``<out>/figures/`` the Pareto and budget figures, ``<out>/<plant>/<tuner>.json`` each gains file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.config import config_file, load_yaml, validate
from gripper_env.disturbances import load_disturbance
from gripper_env.files import write_atomic, write_json
from gripper_env.gains_file import provenance
from gripper_env.metrics import compute_metrics
from gripper_env.objective import load_objective
from gripper_env.pid import PIDGains
from gripper_env.plants import load_plant
from gripper_env.references import load_reference
from gripper_env.scoring import reachability, score_trajectory
from gripper_env.sim import simulate
from tuners import classical, cli, leaderboard, manual
from tuners import optuna as optuna_tuner
from tuners.evaluation import summarize_runs, with_cost
from tuners.search_space import SearchSpace, search_space
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
    search_seeds: int = Field(3, ge=1)


class _RLPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    enabled: bool = True
    algo: str = "ppo"
    timesteps: int = Field(800, ge=1)
    search_seeds: int = Field(3, ge=1)
    controller: bool = True  # the RL controller row (configs/tuners/rl_controller.yaml)


class _RobustPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    plants: list[str] = ["test2", "test3", "test4"]
    rl_timesteps: int = Field(2400, ge=1)


class _QuickPart(BaseModel):
    model_config = ConfigDict(extra="forbid")
    plants: list[str] = ["test1", "test2"]
    samplers: list[str] = ["tpe", "random"]
    optuna_trials: int = Field(32, ge=1)
    search_seeds: int = Field(1, ge=1)
    rl_timesteps: int = Field(128, ge=1)
    robust: bool = False
    pareto_points: int = Field(3, ge=0)


class BenchmarkSettings(BaseModel):
    """``configs/benchmark.yaml`` (see the comments there)."""

    model_config = ConfigDict(extra="forbid")
    plants: list[str] = ["test1", "test2", "test3", "test4"]
    disturbance: str = "actual"
    grip_scenario: str = "grip-object"
    profile: str = "step"
    seed: int = 0
    manual: list[str] = ["paper-untuned", "paper-tuned", "paper-hw-tuned"]
    classical: list[str] = ["simc", "amigo-pi", "amigo-pid", "migo", "pidtune"]
    optuna: _OptunaPart = _OptunaPart()
    rl: _RLPart = _RLPart()
    robust: _RobustPart = _RobustPart()
    pareto_ms: list[float] = [1.2, 1.3, 1.4, 1.5, 1.6, 1.8, 2.0, 2.4]
    quick: _QuickPart = _QuickPart()


# ----------------------------------------------------------------------------------------------
# One row: evaluate a controller as every tuner's gains are evaluated, plus the scenarios


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


def grip_scenario(
    inputs: cli.Inputs, gains: PIDGains | None, sign: int, preset: str
) -> dict[str, Any]:
    """The jaw closing on an object (the ``grip_scenario`` preset) over the held-out seeds:
    mean stall time, force proxy (fraction of stall torque while touching), and the release
    delay (from the un-grip command until the jaw has left the object by 2 deg)."""
    s = inputs.settings
    _, actual = s.options(sign)
    seeds = s.seeds.seeds()
    traj = simulate(
        inputs.plant,
        inputs.reference,
        gains=None if gains is None else np.repeat(gains.as_array()[None, :], len(seeds), 0),
        disturbance=preset,
        seeds=seeds,
        randomize=s.randomize,
        pid_options=actual,
    )
    return grip_summary(traj, inputs, preset)


def grip_summary(traj: Any, inputs: cli.Inputs, preset: str) -> dict[str, Any]:
    """:func:`grip_scenario`'s figures from the scenario's trajectory (any controller's)."""
    ungrip = [seg for seg in inputs.reference.segments if seg.kind == "ungrip"]
    release = []
    for b in range(traj.y_true.shape[0]):
        y = traj.y_true[b]
        if not ungrip or not traj.stable[b]:
            release.append(np.inf)
            continue
        start = ungrip[0].start
        touch = np.min(y[:start])
        left = np.flatnonzero(y[start:] > touch + 2.0)
        release.append(left[0] * inputs.plant.dt_s if len(left) else np.inf)
    rel = np.array(release)
    return {
        "preset": preset,
        "stall_s": float(np.mean(traj.stall_s)),
        "contact_s": float(np.mean(traj.contact_s)),
        "force_proxy": float(np.mean(traj.force_proxy)),
        "release_s": float(np.mean(rel)) if np.isfinite(rel).all() else None,
    }


def _row(
    content: dict[str, Any],
    evaluation: Any,
    kind: str,
    episodes: int,
    wall_s: float,
    grip: dict[str, Any],
) -> dict[str, Any]:
    return {
        "kind": kind,
        "P": content["P"],
        "I": content["I"],
        "D": content["D"],
        "N": content["N"],
        "sign": content["sign"],
        "robustness": content["robustness"],
        "cross_model": content["cross_model"],
        "metrics": content["metrics"],
        "per_seed_iae": [r["iae"] for r in evaluation.actual_runs],
        "per_seed_cost": [r["cost"] for r in evaluation.actual_runs],
        "grip_object": grip,
        "episodes": int(episodes),
        "wall_time_s": float(wall_s),
        "tuning": content["tuning"],
    }


def feedforward_row(inputs: cli.Inputs, preset: str) -> dict[str, Any]:
    """``command = reference``: the servo's own position loop, no feedback from the host."""
    s = inputs.settings
    obj = load_objective()
    seeds = s.seeds.seeds()
    traj = simulate(
        inputs.plant, inputs.reference, disturbance=inputs.disturbance, seeds=seeds,
        randomize=s.randomize,
    )  # fmt: skip
    metrics, costs = score_trajectory(traj, obj, inputs.disturbance)
    runs = with_cost(metrics, costs)
    ideal_traj = simulate(inputs.plant, inputs.reference, disturbance="ideal")
    ideal_m, ideal_c = score_trajectory(ideal_traj, obj, load_disturbance("ideal"))
    reach = reachability(inputs.plant, inputs.reference, inputs.disturbance)
    return {
        "kind": "feedforward",
        "P": None,
        "I": None,
        "D": None,
        "N": None,
        "sign": 1,
        # no feedback from the host: the sensitivity is 1 at every frequency
        "robustness": {
            "stable": True,
            "meets_constraints": True,
            "ms": 1.0,
            "mt": 0.0,
            "gain_margin_db": None,
            "phase_margin_deg": None,
            "note": "open loop",
        },
        "cross_model": {},
        "metrics": {"ideal": with_cost(ideal_m, ideal_c)[0], "actual": summarize_runs(runs)},
        "per_seed_iae": [r["iae"] for r in runs],
        "per_seed_cost": [r["cost"] for r in runs],
        "grip_object": grip_scenario(inputs, None, 1, preset),
        "episodes": 0,
        "wall_time_s": 0.0,
        "tuning": {"bang_bang_iae_bound": reach.iae_bound},
    }


# ----------------------------------------------------------------------------------------------
# The run


class _Recorder:
    """Evaluates gains, writes their gains file and keeps the benchmark row."""

    def __init__(self, out: Path, bench: BenchmarkSettings, log: Callable[..., None], command):
        self.out, self.bench, self.log, self.command = out, bench, log, command

    def __call__(
        self,
        inputs: cli.Inputs,
        rows: dict[str, Any],
        tuner: str,
        kind: str,
        gains: PIDGains,
        sign: int = 1,
        *,
        episodes: int = 0,
        wall: float = 0.0,
        tuning: dict[str, Any] | None = None,
        label: str = "",
    ) -> None:
        content, evaluation = cli.make_result(
            inputs,
            tuner=tuner,
            gains=gains,
            sign=sign,
            label=label,
            seed=self.bench.seed,
            tuning=tuning,
            wall_time_s=wall,
            command=self.command,
        )
        cli.write_result(self.out, inputs, content, evaluation)
        grip = grip_scenario(inputs, gains, sign, self.bench.grip_scenario)
        rows[tuner] = _row(content, evaluation, kind, episodes, wall, grip)
        iae = content["metrics"]["actual"]["mean"]["iae"]
        ok = "meets" if content["robustness"]["meets_constraints"] else "MISSES"
        self.log(
            f"  {inputs.plant.name:6s} {tuner:24s} IAE {iae:8.3f}  Ms "
            f"{content['robustness']['ms'] or float('nan'):5.2f}  {ok} the constraints"
        )


def _searches(
    inputs: cli.Inputs,
    rows: dict[str, Any],
    record: _Recorder,
    opt: OptunaSettings,
    samplers: list[str],
    trials: int,
    seeds: int,
    base_seed: int,
) -> dict[str, list]:
    """Optuna with each sampler over ``seeds`` search seeds: the best kept, the spread kept."""
    curves = {}
    for sampler in samplers:
        t0 = time.perf_counter()
        results, episodes = [], 0
        for i in range(seeds):
            result, scorer, space = optuna_tuner.search(
                inputs, opt, n_trials=trials, sampler_name=sampler, seed=base_seed + i
            )
            results.append(result)
            episodes += scorer.episodes
        wall = time.perf_counter() - t0
        chosen = optuna_tuner.best_of(results)
        best = results[chosen]
        name = optuna_tuner.tuner_name(sampler, False)
        curves[name] = best.history
        record(
            inputs, rows, name, "search", best.gains, episodes=episodes, wall=wall,
            tuning={
                "sampler": sampler,
                "trials_per_seed": trials,
                "feasible": best.feasible,
                "best_value_tuning": best.best_value,
                "history": best.history,
                "on_bound": space.on_bound(best.gains),
                "search_space": space.as_dict(),
                **optuna_tuner.seed_summary(results, [base_seed + i for i in range(seeds)]),
            },
        )  # fmt: skip
    return curves


def _rl_rows(
    inputs: cli.Inputs,
    rows: dict[str, Any],
    record: _Recorder,
    rl_module: Any,
    timesteps: int,
    seeds: int,
    bench: BenchmarkSettings,
    out: Path,
) -> list:
    """The RL tuner (PPO on GripperPIDTune-v0) over ``seeds`` training seeds."""
    t0 = time.perf_counter()
    runs = [
        rl_module.benchmark_tune(
            inputs, timesteps=timesteps, seed=bench.seed + i, algo=bench.rl.algo, out=out
        )
        for i in range(seeds)
    ]
    wall = time.perf_counter() - t0
    costs = [r["best_value_tuning"] if r["best_value_tuning"] is not None else np.inf for r in runs]
    chosen = int(np.argmin(costs))
    best = runs[chosen]
    record(
        inputs, rows, "rl-budget", "search", best["gains"],
        episodes=sum((r["episodes"] or 0) + r["selection_episodes"] for r in runs), wall=wall,
        tuning={
            "algo": bench.rl.algo,
            "timesteps_per_seed": timesteps,
            "history": best["history"],
            "best_value_tuning": best["best_value_tuning"],
            "search_seeds": [bench.seed + i for i in range(seeds)],
            "on_bound": _space(inputs, [inputs.plant.name]).on_bound(best["gains"]),
            "best_cost": {"min": float(np.min(costs)), "median": float(np.median(costs)),
                          "max": float(np.max(costs))},
            "per_seed": [
                {"seed": bench.seed + i, "best_value_tuning": r["best_value_tuning"],
                 "P": r["gains"].P, "I": r["gains"].I, "D": r["gains"].D}
                for i, r in enumerate(runs)
            ],
        },
    )  # fmt: skip
    return best["history"]


def _robust_tuners(
    bench: BenchmarkSettings,
    ev: EvaluationSettings,
    opt: OptunaSettings,
    quick: bool,
    rl_module: Any,
    out: Path,
    log: Callable[..., None],
) -> dict[str, Any]:
    """Gains tuned once on several identifications (Optuna robust mode, plant-conditioned RL)."""
    plants = bench.robust.plants
    inputs = _inputs(plants[0], bench, ev)
    trials = bench.quick.optuna_trials if quick else bench.optuna.trials
    seeds = bench.quick.search_seeds if quick else bench.optuna.search_seeds
    t0 = time.perf_counter()
    results, episodes = [], 0
    for i in range(seeds):
        result, scorer, space = optuna_tuner.search(
            inputs, opt, n_trials=trials, seed=bench.seed + i, plants=plants
        )
        results.append(result)
        episodes += scorer.episodes
    chosen = optuna_tuner.best_of(results)
    robust: dict[str, Any] = {
        "optuna-robust": {
            "gains": results[chosen].gains,
            "episodes": episodes,
            "wall": time.perf_counter() - t0,
            "tuning": {
                "tuned_on": plants,
                "feasible": results[chosen].feasible,
                "on_bound": space.on_bound(results[chosen].gains),
                **optuna_tuner.seed_summary(results, [bench.seed + i for i in range(seeds)]),
            },
        }
    }
    log(f"  optuna-robust on {'+'.join(plants)}: {results[chosen].gains}")
    if rl_module is not None:
        t0 = time.perf_counter()
        steps = bench.quick.rl_timesteps if quick else bench.robust.rl_timesteps
        facts = rl_module.train(
            inputs, plants, algo=bench.rl.algo, timesteps=steps, seed=bench.seed,
            run_dir=out / "rl" / f"benchmark-pid-tune-{bench.rl.algo}-{'+'.join(plants)}",
            n_envs=16, eval_every=max(16, steps // 16),
        )  # fmt: skip
        model = facts.pop("model")
        robust["rl-conditioned"] = {
            "policy": (model, facts["env_kwargs"]),
            "episodes": (facts["episodes"] or 0) + facts["selection_episodes"],
            "wall": time.perf_counter() - t0,
            "tuning": {
                "tuned_on": plants,
                "timesteps": steps,
                "history": facts["history"],
                "space": _space(inputs, plants),
            },
        }
    return robust


def run_benchmark(
    bench: BenchmarkSettings,
    ev: EvaluationSettings,
    opt: OptunaSettings,
    cls: ClassicalSettings,
    out: Path,
    quick: bool = False,
    log: Callable[..., None] = print,
    command: str | None = None,
) -> dict[str, Any]:
    """Run every tuner on every plant; write gains files and return the benchmark's data."""
    q = bench.quick
    plants = q.plants if quick else bench.plants
    samplers = q.samplers if quick else bench.optuna.samplers
    trials = q.optuna_trials if quick else bench.optuna.trials
    seeds = q.search_seeds if quick else bench.optuna.search_seeds
    rl_steps = q.rl_timesteps if quick else bench.rl.timesteps
    rl_seeds = q.search_seeds if quick else bench.rl.search_seeds
    per_study = trials * opt.tuning_seeds.count
    data: dict[str, Any] = {
        "plants": {},
        "budget_episodes": per_study * seeds,
        "budget_per_seed": per_study,
        "search_seeds": seeds,
    }
    rl_module, data["rl_note"] = _rl_module(bench)
    record = _Recorder(out, bench, log, command)
    robust = None
    if not quick or q.robust:
        robust = _robust_tuners(bench, ev, opt, quick, rl_module, out, log)
    for plant in plants:
        inputs = _inputs(plant, bench, ev)
        reach = reachability(inputs.plant, inputs.reference, inputs.disturbance)
        if not reach.feasible:
            data["plants"][plant] = {
                "feasible": False,
                "reason": reach.reason(),
                "reached_fraction": reach.reached_fraction,
                "iae_bound": reach.iae_bound,
            }
            log(f"  {plant}: {reach.reason()}; not tuned, not ranked")
            continue
        rows: dict[str, Any] = {}
        rows["command=reference"] = feedforward_row(inputs, bench.grip_scenario)
        for preset in bench.manual:
            chosen = manual.PAPER_GAINS[preset]
            record(inputs, rows, f"manual-{preset}", "manual", chosen.gains, chosen.sign,
                   label=preset)  # fmt: skip
        for method in bench.classical:
            t0 = time.perf_counter()
            gains, tuning = classical.design(
                method, inputs.plant, inputs.disturbance, cls, ev.pid.N
            )
            record(inputs, rows, f"classical-{method}", "baseline", gains,
                   wall=time.perf_counter() - t0, tuning=tuning, label=method)  # fmt: skip
        curves = _searches(inputs, rows, record, opt, samplers, trials, seeds, bench.seed)
        if rl_module is not None:
            curves["rl-budget"] = _rl_rows(
                inputs, rows, record, rl_module, rl_steps, rl_seeds, bench, out
            )
        if robust is not None:
            _robust_rows(inputs, rows, record, robust, rl_module)
        if rl_module is not None and bench.rl.controller:
            _controller_row(inputs, rows, rl_module, bench, quick, out, log, command)
        front = _pareto_front(inputs, bench, cls, quick)
        data["plants"][plant] = {
            "feasible": True,
            "iae_bound": reach.iae_bound,
            "tuners": rows,
            "curves": curves,
            "pareto_front": front,
        }
    return data


def _space(inputs: cli.Inputs, plants: list[str]) -> SearchSpace:
    """The search ranges of these plants (the RL tuner's action box spans the same gains)."""
    return search_space(
        [load_plant(p) for p in plants], inputs.disturbance, load_settings(OptunaSettings)
    )


def _rl_module(bench: BenchmarkSettings) -> tuple[Any, str | None]:
    if not bench.rl.enabled:
        return None, "RL tuner disabled in the benchmark config"
    try:
        from tuners import rl as rl_module  # needs gripper_env.envs and stable-baselines3
    except ImportError as exc:
        return None, (
            f"RL tuner not run: it needs the Gymnasium environments and stable-baselines3 ({exc})"
        )
    return rl_module, None


def _controller_row(
    inputs: cli.Inputs,
    rows: dict[str, Any],
    rl_module: Any,
    bench: BenchmarkSettings,
    quick: bool,
    out: Path,
    log: Callable[..., None],
    command: str | None,
) -> None:
    """The RL controller (a PPO residual policy): trained to correct this plant's best
    deployable PID (the ranked row of lowest cost so far), scored on the same seeds."""
    pids = [
        n for n, r in rows.items()
        if r["P"] is not None and r["sign"] == 1 and leaderboard.why_not_ranked(r) is None
    ]  # fmt: skip
    if not pids:
        log(f"  {inputs.plant.name}: no deployable PID to base the RL controller on; skipped")
        return
    best = min(pids, key=lambda n: rows[n]["metrics"]["actual"]["mean"]["cost"])
    r = rows[best]
    base = PIDGains(r["P"], r["I"], r["D"], r["N"])
    row = rl_module.controller_row(
        inputs, base, out=out, quick=quick, grip_preset=bench.grip_scenario,
        log=log, command=command,
    )  # fmt: skip
    row["tuning"]["base_tuner"] = best
    rows["rl-controller"] = row
    a, b = row["metrics"]["actual"]["mean"], r["metrics"]["actual"]["mean"]
    log(
        f"  {inputs.plant.name:6s} {'rl-controller':24s} IAE {a['iae']:8.3f}  (its base "
        f"{best}: {b['iae']:.3f}; trained {row['tuning']['timesteps']} steps)"
    )


def _robust_rows(
    inputs: cli.Inputs,
    rows: dict[str, Any],
    record: _Recorder,
    robust: dict[str, Any],
    rl_module: Any,
) -> None:
    for name, r in robust.items():
        tuning = dict(r["tuning"])
        if name == "rl-conditioned":
            model, kwargs = r["policy"]
            gains = rl_module.policy_gains(model, rl_module.ENV_IDS["pid-tune"], kwargs,
                                           inputs.plant.name)  # fmt: skip
            tuning["on_bound"] = tuning.pop("space").on_bound(gains)
        else:
            gains = r["gains"]
        record(inputs, rows, name, "robust", gains, episodes=r["episodes"], wall=r["wall"],
               tuning=tuning)  # fmt: skip


def _pareto_front(
    inputs: cli.Inputs, bench: BenchmarkSettings, cls: ClassicalSettings, quick: bool
) -> list[dict[str, float]]:
    """The tracking-robustness trade-off: MIGO designs for a range of Ms limits (the largest
    integral gain each Ms allows), each scored on the held-out seeds."""
    levels = bench.pareto_ms
    if quick:
        levels = levels[:: max(1, len(levels) // max(1, bench.quick.pareto_points))][
            : bench.quick.pareto_points
        ]
    front = []
    s = inputs.settings
    _, actual = s.options(1)
    obj = load_objective()
    for ms in levels:
        try:
            gains, _ = classical.design(
                "migo", inputs.plant, inputs.disturbance,
                cls.model_copy(update={"migo_ms": ms}), s.pid.N,
            )  # fmt: skip
        except ValueError:
            continue
        traj = simulate(
            inputs.plant, inputs.reference,
            gains=np.repeat(gains.as_array()[None, :], s.seeds.count, 0),
            disturbance=inputs.disturbance, seeds=s.seeds.seeds(), randomize=s.randomize,
            pid_options=actual,
        )  # fmt: skip
        metrics = compute_metrics(
            traj, obj.signal, settling_band_deg=obj.settling_band_deg(inputs.disturbance)
        )
        front.append(
            {"ms": ms, "iae": float(np.mean(metrics.run["iae"])), "P": gains.P, "I": gains.I}
        )
    return front


# ----------------------------------------------------------------------------------------------
# Command line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.benchmark",
        description="Run every tuner on every plant and rank them as a control engineer would.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--config", type=Path, default=config_file("benchmark.yaml"), help="benchmark settings"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="small search budgets and two plants (a few minutes); what the test runs",
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
    for plant in {*bench.plants, *bench.quick.plants, *bench.robust.plants}:
        load_plant(plant)
    load_disturbance(bench.disturbance)
    load_disturbance(bench.grip_scenario)
    load_reference(bench.profile)
    for preset in bench.manual:
        if preset not in manual.PAPER_GAINS:
            raise ValueError(f"{args.config}: unknown manual preset {preset!r}")
    for method in bench.classical:
        if method not in classical.METHODS:
            raise ValueError(f"{args.config}: unknown classical method {method!r}")
    for sampler in {*bench.optuna.samplers, *bench.quick.samplers}:
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
        grip_scenario=bench.grip_scenario,
        n_seeds=ev.seeds.count,
        tuning_seeds=opt.tuning_seeds.count,
        objective=load_objective().model_dump(),
    )
    data["leaderboard"] = leaderboard.rank(data)
    leaderboard.figures(data, args.out)
    content = {"provenance": meta, **data}
    write_json(args.out / "benchmark.json", content)
    write_atomic(args.out / "benchmark.md", leaderboard.render_markdown(data, meta))
    if args.json:
        print(json.dumps(json.loads((args.out / "benchmark.json").read_text()), indent=2))
    else:
        print(leaderboard.render_head(data))
        print(
            f"wrote {args.out / 'benchmark.md'} and {args.out / 'benchmark.json'} in {wall:.0f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))

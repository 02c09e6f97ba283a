"""Learn PID gains (or a controller) with stable-baselines3 on the Gymnasium environments.

Usage::

    python -m tuners.rl train --plant test2                        # PPO on GripperPIDTune-v0
    python -m tuners.rl train --plant test2 --algo sac --timesteps 20000
    python -m tuners.rl export --plant test2                       # the policy's gains file
    python -m tuners.rl train --plant test1,test2,test3            # plant-conditioned policy
    python -m tuners.rl export --plant test4 --run pid-tune-ppo-test1+test2+test3
    python -m tuners.rl train --plant test2 --env gain-schedule     # or servo: metrics only
    python -m tuners.rl controller --plant test2                   # the RL controller
    tensorboard --logdir results/rl

``pid-tune`` is a contextual bandit: one step chooses P, I, D for a whole 20 s episode, the reward
is minus the shared objective's cost (the cost Optuna minimises), and the observation describes
the plant, the actual-gripper parameters (randomised per episode) and the reference. Training
uses the environments' native vector form (one call of the simulation core for all ``--n-envs``
episodes) behind a stable-baselines3 ``VecEnv``. Every ``--eval-every`` episodes the policy's
deterministic gains are scored like an Optuna trial (same tuning seeds, same cost), which gives
the budget curve (best cost against simulated episodes); an ``EvalCallback`` keeps the best
model, a ``CheckpointCallback`` saves checkpoints, TensorBoard logs go to ``<run>/tb``. A run
lives in ``<out>/rl/<run>/`` (``model.zip``, ``best/``, ``checkpoints/``, ``tb/``,
``history.json``); ``export`` writes ``<out>/<plant>/rl.json`` (a gains file) for the plant given.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.config import ConfigError
from gripper_env.disturbances import load_disturbance
from gripper_env.files import write_json
from gripper_env.objective import load_objective
from gripper_env.pid import PIDGains
from gripper_env.plants import load_plant
from gripper_env.scoring import score_trajectory
from tuners import cli
from tuners.rl_controller import controller_row  # the benchmark's RL-controller row
from tuners.search_space import search_space
from tuners.settings import OptunaSettings, load_settings

__all__ = ["ENV_IDS", "benchmark_tune", "controller_row", "main", "policy_gains", "train"]

ENV_IDS = {
    "pid-tune": "gripper_env/GripperPIDTune-v0",
    "gain-schedule": "gripper_env/GripperGainSchedule-v0",
    "servo": "gripper_env/GripperServo-v0",
}
#: Action range of the gains (P, I, D) at |a| = 1 when no plant scales them (see
#: :func:`gain_max`).
GAIN_MAX = (10.0, 100.0, 0.1)


def gain_max(inputs: cli.Inputs, plants: list[str]) -> tuple[float, float, float]:
    """The action range of the gains: the largest magnitudes of the Optuna search ranges,
    scaled from the plants (:mod:`tuners.search_space`), so both tuners search the same box."""
    space = search_space(
        [load_plant(p) for p in plants], inputs.disturbance, load_settings(OptunaSettings)
    )
    r = space.ranges
    return (
        max(abs(r["P"].low), abs(r["P"].high)),
        max(abs(r["I"].low), abs(r["I"].high)),
        max(abs(r["D"].low), abs(r["D"].high)),
    )


def _require_envs():
    try:
        import gymnasium as gym
        import stable_baselines3  # noqa: F401

        import gripper_env.envs  # noqa: F401 - registers the environments
    except ImportError as exc:
        raise ConfigError(
            f"tuners.rl needs the Gymnasium environments and stable-baselines3 ({exc}); "
            "pip install -e '.[rl]'"
        ) from None
    return gym


def env_kwargs(inputs: cli.Inputs, plants: list[str], env: str) -> dict[str, Any]:
    """Keyword arguments of the environment: plants, preset, reference, PID structure."""
    _, actual = inputs.settings.options(1)
    kwargs: dict[str, Any] = {
        "plant": plants if len(plants) > 1 else plants[0],
        "disturbance": inputs.disturbance_name,
        "reference": inputs.profile_name,
        "randomize": inputs.settings.randomize,
        "pid_options": {
            "output_limits": actual.output_limits,
            "anti_windup": actual.anti_windup,
            "derivative_on": actual.derivative_on,
            "sign": 1,
        },
    }
    if env in ("pid-tune", "gain-schedule"):
        kwargs["gain_max"] = gain_max(inputs, plants)
        kwargs["derivative_filter"] = inputs.settings.pid.N
    if env == "servo":
        kwargs.pop("pid_options")
    return kwargs


def make_vec_env(env: str, kwargs: dict[str, Any], n_envs: int, seed: int):
    """A stable-baselines3 VecEnv of ``n_envs`` environments: the native vector environment
    (one core call per step) through :class:`gripper_env.sb3.NativeVecEnv`, under ``VecMonitor``
    (episode returns for the logs and the evaluation callback)."""
    _require_envs()
    from stable_baselines3.common.vec_env import VecMonitor

    from gripper_env.sb3 import NativeVecEnv

    vec = VecMonitor(NativeVecEnv(ENV_IDS[env], num_envs=n_envs, **kwargs))
    vec.seed(seed)
    return vec


def policy_gains(model: Any, env_id: str, kwargs: dict[str, Any], plant: str) -> PIDGains:
    """The gains a ``pid-tune`` policy chooses (deterministically) for one plant's nominal
    context (the preset's own friction and noise, the configured reference)."""
    gym = _require_envs()
    from gripper_env.envs.spaces import action_to_gains

    one = dict(kwargs, plant=plant, randomize=False)
    env = gym.make(env_id, **one)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    env.close()
    g = action_to_gains(np.asarray(action, dtype=float)[None, :], one.get("gain_max", GAIN_MAX))[0]
    return PIDGains(
        float(g[0]), float(g[1]), float(g[2]), float(kwargs.get("derivative_filter", 100.0))
    )


def evaluate_controller(
    model: Any,
    env_id: str,
    kwargs: dict[str, Any],
    plant: str,
    seeds: list[int],
    profile: str,
    objective: Any = None,
) -> dict[str, Any]:
    """Metrics of a ``gain-schedule`` or ``servo`` policy over held-out episodes.

    The deterministic policy runs one episode per seed (:func:`gripper_env.envs.rollout.
    policy_trajectory`: the episodes :func:`~gripper_env.sim.simulate` runs for those
    seeds) and the trajectories are scored through the one scoring path
    (:func:`gripper_env.scoring.score_trajectory`, the objective's signal), summarised like a
    gains file's ``actual`` block.
    """
    _require_envs()
    from gripper_env.envs.rollout import policy_trajectory
    from tuners.evaluation import summarize_runs, with_cost

    def policy(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    one = dict(kwargs, plant=plant, reference=profile)
    traj = policy_trajectory(policy, seeds, env_id=env_id, **one)
    disturbance = load_disturbance(kwargs.get("disturbance", "actual"))
    metrics, costs = score_trajectory(traj, objective or load_objective(), disturbance)
    rows = with_cost(metrics, costs)
    return summarize_runs(rows)


def _algo(name: str):
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[name]


def _algo_kwargs(name: str, env: str, n_envs: int) -> dict[str, Any]:
    if name == "ppo":
        if env == "pid-tune":  # a bandit: no bootstrapping, large batches of whole episodes
            return {
                "n_steps": max(1, 256 // n_envs),
                "batch_size": 64,
                "gamma": 0.0,
                "gae_lambda": 0.0,
                "n_epochs": 10,
                "learning_rate": 1e-3,
                "ent_coef": 0.0,
            }
        return {"n_steps": 512, "batch_size": 128}
    if env == "pid-tune":
        return {
            "gamma": 0.0,
            "learning_starts": 256,
            "batch_size": 128,
            "train_freq": 1,
            "gradient_steps": 1,
        }
    return {}


def train(
    inputs: cli.Inputs,
    plants: list[str],
    *,
    env: str = "pid-tune",
    algo: str = "ppo",
    timesteps: int = 20000,
    n_envs: int = 16,
    seed: int = 0,
    run_dir: Path,
    eval_every: int = 512,
    optuna_settings: OptunaSettings | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Train a policy; return the history (episodes, best cost) and the run's facts."""
    _require_envs()
    kwargs = env_kwargs(inputs, plants, env)
    vec = make_vec_env(env, kwargs, n_envs, seed)
    eval_env = make_vec_env(env, kwargs, 1 if env != "pid-tune" else 8, seed + 10_000)
    cls = _algo(algo)
    model = cls(
        "MlpPolicy",
        vec,
        seed=seed,
        verbose=0,
        tensorboard_log=str(run_dir / "tb"),
        device="cpu",
        **_algo_kwargs(algo, env, n_envs),
    )
    opt = optuna_settings or load_settings(OptunaSettings)
    history: list[tuple[int, float]] = []
    start = time.perf_counter()
    curve = _budget_curve(inputs, plants, env, kwargs, eval_every, opt, history)
    callbacks = _callbacks(curve, eval_env, run_dir, algo, eval_every, n_envs)
    model.learn(total_timesteps=timesteps, callback=callbacks, progress_bar=progress)
    wall = time.perf_counter() - start
    run_dir.mkdir(parents=True, exist_ok=True)
    model.save(run_dir / "model.zip")
    facts = {
        "env": env,
        "env_id": ENV_IDS[env],
        "env_kwargs": kwargs,
        "algo": algo,
        "plants": plants,
        "timesteps": timesteps,
        "episodes": int(model.num_timesteps) if env == "pid-tune" else None,
        "n_envs": n_envs,
        "seed": seed,
        "train_wall_time_s": wall,
        "history": history,
        "best_gains": None if curve.best_gains is None else curve.best_gains.as_array().tolist(),
        "selection_episodes": curve.scorer.episodes,  # scoring the proposals on the tuning seeds
    }
    write_json(run_dir / "history.json", facts)
    vec.close()
    eval_env.close()
    return {"model": model, **facts}


def _budget_curve(
    inputs: cli.Inputs,
    plants: list[str],
    env: str,
    kwargs: dict[str, Any],
    eval_every: int,
    opt: OptunaSettings,
    history: list[tuple[int, float]],
) -> Any:
    """A callback that scores the policy's gains on the tuning seeds every ``eval_every`` steps,
    like an Optuna trial, appending ``(steps, best feasible cost)`` to ``history``."""
    from stable_baselines3.common.callbacks import BaseCallback

    from tuners.optuna import make_scorer

    class BudgetCurve(BaseCallback):
        """Score the policy's gains on the tuning seeds, like an Optuna trial."""

        def __init__(self) -> None:
            super().__init__()
            self.next_at = 0
            self.best = float("inf")
            self.best_gains: PIDGains | None = None
            self.scorer = make_scorer(inputs, opt, plants[:1])  # an Optuna trial's scorer

        def _on_step(self) -> bool:
            if env == "pid-tune" and self.num_timesteps >= self.next_at:
                self.next_at = self.num_timesteps + eval_every
                g = policy_gains(self.model, ENV_IDS[env], kwargs, plants[0])
                scores = self.scorer.score(g.as_array()[None, :])
                cost = float(scores.cost[0])
                if scores.feasible[0] and cost < self.best:  # like Optuna's best trial
                    self.best, self.best_gains = cost, g
                if np.isfinite(self.best):
                    history.append((int(self.num_timesteps), self.best))
                self.logger.record("tuning/policy_cost", cost)
                self.logger.record("tuning/policy_feasible", float(scores.feasible[0]))
            return True

    return BudgetCurve()


def _callbacks(
    curve: Any, eval_env: Any, run_dir: Path, algo: str, eval_every: int, n_envs: int
) -> Any:
    """The budget curve, checkpoints every ten and evaluations every four of its periods."""
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback

    return CallbackList(
        [
            curve,
            CheckpointCallback(
                save_freq=max(1, 10 * eval_every // n_envs),
                save_path=str(run_dir / "checkpoints"),
                name_prefix=algo,
            ),
            EvalCallback(
                eval_env,
                n_eval_episodes=8,
                eval_freq=max(1, 4 * eval_every // n_envs),
                best_model_save_path=str(run_dir / "best"),
                log_path=str(run_dir / "eval"),
                deterministic=True,
                verbose=0,
            ),
        ]
    )


def benchmark_tune(inputs: cli.Inputs, *, timesteps: int, seed: int, algo: str, out: Path):
    """Train ``pid-tune`` on one plant and return gains and the budget curve (benchmark)."""
    run_dir = Path(out) / "rl" / f"benchmark-pid-tune-{algo}-{inputs.plant.name}"
    facts = train(
        inputs,
        [inputs.plant.name],
        algo=algo,
        timesteps=timesteps,
        seed=seed,
        run_dir=run_dir,
        n_envs=16,
        eval_every=max(16, timesteps // 16),
    )
    # like Optuna's best trial: the best feasible gains the policy proposed during training
    # (scored on the tuning seeds), else the final policy's
    if facts["best_gains"] is not None:
        gains = PIDGains(*facts["best_gains"])
    else:
        gains = policy_gains(
            facts["model"], ENV_IDS["pid-tune"], facts["env_kwargs"], inputs.plant.name
        )
    facts.pop("model")
    return {
        "gains": gains,
        **facts,
        "best_value_tuning": facts["history"][-1][1] if facts["history"] else None,
    }


# ----------------------------------------------------------------------------------------------
# Command line


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rl",
        description="Learn PID gains (or a controller) with stable-baselines3.",
    )
    sub = parser.add_subparsers(dest="command_name", required=True)
    tr = sub.add_parser(
        "train", help="train a policy", formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ex = sub.add_parser(
        "export",
        help="turn a pid-tune policy into a gains file",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    for p in (tr, ex):
        p.add_argument(
            "--plant",
            required=True,
            help="plant, or a comma-separated list (train: a plant-conditioned "
            "policy; export: the plant to give gains for)",
        )
        p.add_argument("--disturbance", default="actual", help="actual-gripper preset")
        p.add_argument("--profile", default="step", help="reference profile")
        p.add_argument("--seed", type=int, default=0, help="random seed")
        p.add_argument("--out", type=Path, default=Path("results"), help="output folder")
        p.add_argument("--json", action="store_true", help="print JSON instead of a table")
        p.add_argument("--eval-config", type=Path, default=None, help="evaluation settings")
        p.add_argument(
            "--env",
            choices=tuple(ENV_IDS),
            default="pid-tune",
            help="environment: pid-tune (gains per episode), gain-schedule, servo",
        )
        p.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="algorithm")
    tr.add_argument("--timesteps", type=int, default=20000, help="environment steps")
    tr.add_argument("--n-envs", type=int, default=16, help="parallel environments")
    tr.add_argument(
        "--eval-every",
        type=int,
        default=512,
        help="score the policy's gains every this many steps (budget curve)",
    )
    ex.add_argument(
        "--run", default=None, help="run folder name under OUT/rl (default: <env>-<algo>-<plant>)"
    )
    co = sub.add_parser(
        "controller",
        help="train the RL controller (a residual policy) and score it against its baselines",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    co.add_argument("--plant", required=True, help="plant")
    co.add_argument("--disturbance", default="actual", help="actual-gripper preset")
    co.add_argument("--profile", default="step", help="reference profile of the evaluation")
    co.add_argument("--out", type=Path, default=Path("results"), help="output folder")
    co.add_argument("--json", action="store_true", help="print JSON instead of a table")
    co.add_argument("--eval-config", type=Path, default=None, help="evaluation settings")
    co.add_argument(
        "--config",
        type=Path,
        default=None,
        help="controller settings (default configs/tuners/rl_controller.yaml)",
    )
    co.add_argument(
        "--residual",
        choices=("pid", "reference"),
        default=None,
        help="what the policy corrects (default: the config's)",
    )
    co.add_argument(
        "--base",
        default=None,
        help="the PID it corrects: a gains file, or P,I,D[,N] (default: OUT/<plant>/optuna.json)",
    )
    co.add_argument("--timesteps", type=int, default=None, help="training steps (default: config)")
    co.add_argument("--quick", action="store_true", help="the config's quick_timesteps")
    co.add_argument("--seed", type=int, default=None, help="training seed (default: config)")
    return parser


def _base_gains(spec: str | None, out: Path, plant: str) -> PIDGains:
    """The PID a residual controller corrects: ``P,I,D[,N]`` or a gains file (sign +1)."""
    from gripper_env.gains_file import load_gains_file

    if spec is not None and "," in spec and not Path(spec).exists():
        try:
            values = [float(x) for x in spec.split(",")]
        except ValueError:
            values = []
        if len(values) not in (3, 4) or not all(np.isfinite(values)):
            raise ValueError(f"--base: expected P,I,D[,N] or a gains file, got {spec!r}")
        n_filter = values[3] if len(values) == 4 else 100.0
        return PIDGains(values[0], values[1], values[2], n_filter)
    path = Path(spec) if spec is not None else out / plant / "optuna.json"
    if spec is None and not path.is_file():
        raise ValueError(
            f"no base PID: {path} does not exist; run 'python -m tuners.optuna --plant {plant}' "
            "first, or give --base P,I,D or --base <gains file>"
        )
    loaded = load_gains_file(path)
    if loaded.options.sign != 1:
        raise ValueError(f"--base: {path} uses the error sign -1; the residual PID takes +1")
    return loaded.gains


def _controller(args: argparse.Namespace, inputs: cli.Inputs) -> int:
    from tuners.rl_controller import load_controller_settings

    s = load_controller_settings(args.config)
    updates: dict[str, Any] = {}
    if args.residual is not None:
        updates["residual"] = args.residual
    if args.timesteps is not None:
        if args.timesteps < 1:
            raise ValueError("--timesteps must be at least 1")
        updates["timesteps"] = args.timesteps
    if args.seed is not None:
        updates["seed"] = args.seed
    s = s.model_copy(update=updates)
    base = _base_gains(args.base, args.out, inputs.plant.name) if s.residual == "pid" else None
    row = controller_row(
        inputs, base, settings=s, out=args.out, quick=args.quick,
        log=(lambda m: None) if args.json else print, command=args.command,
    )  # fmt: skip
    path = args.out / inputs.plant.name / "rl-controller.json"
    if args.json:
        print(path.read_text())
        return 0
    base_name = "the base PID" if s.residual == "pid" else "command = reference"
    columns = [
        ("RL controller", row["metrics"]["actual"]),
        (base_name, row["tuning"]["baselines"]["base"]["actual"]),
        ("command = reference", row["tuning"]["baselines"]["command_equals_reference"]["actual"]),
    ]
    if s.residual == "reference":
        columns.pop(1)
    print(
        f"{inputs.plant.name}, actual model, mean of {len(inputs.settings.seeds.seeds())} "
        f"held-out seeds ({load_objective().signal} angle); trained "
        f"{row['tuning']['timesteps']} steps in {row['tuning']['train_wall_time_s']:.0f} s"
    )
    print(f"{'':22s}" + "".join(f"{name:>22s}" for name, _ in columns))
    for label, path_ in (("IAE deg*s", ("iae",)), ("grip overshoot %", ("grip", "overshoot_pct")),
                         ("un-grip overshoot %", ("ungrip", "overshoot_pct")),
                         ("stall s", ("stall_s",)), ("servo effort deg", ("servo_effort_deg",)),
                         ("cost", ("cost",))):  # fmt: skip
        cells = []
        for _, metrics in columns:
            value: Any = metrics["mean"]
            for key in path_:
                value = value.get(key) if isinstance(value, dict) else None
            cells.append("-" if value is None else f"{value:.4g}")
        print(f"{label:22s}" + "".join(f"{c:>22s}" for c in cells))
    for label, key in (("the base PID", "vs_base"),
                       ("command = reference", "vs_command_equals_reference")):  # fmt: skip
        d = row["tuning"][key]
        if key == "vs_base" and s.residual != "pid":
            continue
        print(f"RL controller vs {label}: IAE {d['iae_difference']:+.3g} deg*s "
              f"({100 * d['iae_relative']:+.1f} %, lower on {d['iae_better_on_seeds']} of "
              f"{len(row['per_seed_iae'])} seeds, Wilcoxon p = {d['iae_p_value']:.3g}), worse "
              f"overshoot {d['worse_overshoot_difference_pct']:+.3g} %, stall "
              f"{d['stall_difference_s']:+.3g} s")  # fmt: skip
    print(f"wrote {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    if args.command_name == "controller":
        _require_envs()
        return _controller(args, cli.resolve(args))
    plants = [p.strip() for p in args.plant.split(",") if p.strip()]
    for p in plants:
        load_plant(p)
    args.plant = plants[0]
    inputs = cli.resolve(args)
    _require_envs()
    if args.command_name == "train":
        return _train_command(args, inputs, plants)
    return _export(args, inputs)


def _train_command(args: argparse.Namespace, inputs: cli.Inputs, plants: list[str]) -> int:
    """``train``: train a policy and say where it went."""
    if args.timesteps < 1 or args.n_envs < 1:
        raise ValueError("--timesteps and --n-envs must be at least 1")
    run = f"{args.env}-{args.algo}-{'+'.join(plants)}"
    facts = train(
        inputs,
        plants,
        env=args.env,
        algo=args.algo,
        timesteps=args.timesteps,
        n_envs=args.n_envs,
        seed=args.seed,
        run_dir=args.out / "rl" / run,
        eval_every=args.eval_every,
        progress=not args.json,
    )
    facts.pop("model")
    if args.json:
        print(json.dumps(json.loads((args.out / "rl" / run / "history.json").read_text())))
    else:
        best = facts["history"][-1][1] if facts["history"] else None
        print(
            f"trained {run}: {facts['timesteps']} steps in "
            f"{facts['train_wall_time_s']:.0f} s; best policy cost on the tuning seeds "
            f"{best}; wrote {args.out / 'rl' / run}"
        )
    return 0


def _export(args: argparse.Namespace, inputs: cli.Inputs) -> int:
    """``export``: a trained run's gains as a gains file (``pid-tune``), or a controller's
    metrics (the other environments)."""
    run = args.run or f"{args.env}-{args.algo}-{args.plant}"
    path = args.out / "rl" / run / "model.zip"
    if not path.is_file():
        raise ValueError(f"no trained model at {path}; run 'python -m tuners.rl train' first")
    facts = json.loads((args.out / "rl" / run / "history.json").read_text())
    model = _algo(facts["algo"]).load(path, device="cpu")
    if facts["env"] != "pid-tune":  # a controller, not gains: report its metrics
        return _export_controller_metrics(args, inputs, run, model, facts)
    kwargs = env_kwargs(inputs, facts["plants"], "pid-tune")
    gains = policy_gains(model, ENV_IDS["pid-tune"], kwargs, args.plant)
    held_out = args.plant not in facts["plants"]
    cli.publish(
        args,
        inputs,
        tuner="rl" if facts["plants"] == [args.plant] else "rl-conditioned",
        gains=gains,
        sign=1,
        label=run,
        tuning={
            "run": run,
            "trained_on": facts["plants"],
            "held_out_plant": held_out,
            "algo": facts["algo"],
            "timesteps": facts["timesteps"],
            "train_wall_time_s": facts["train_wall_time_s"],
            "history": facts["history"],
        },
    )
    return 0


def _export_controller_metrics(
    args: argparse.Namespace, inputs: cli.Inputs, run: str, model: Any, facts: dict[str, Any]
) -> int:
    """A trained controller's metrics on the held-out seeds, written and printed."""
    kwargs = env_kwargs(inputs, facts["plants"], facts["env"])
    seeds = [int(s) for s in inputs.settings.seeds.seeds()]
    actual = evaluate_controller(
        model, ENV_IDS[facts["env"]], kwargs, args.plant, seeds, inputs.profile_name
    )
    content = {
        "format": "gripper-policy-metrics",
        "plant": args.plant,
        "tuner": f"rl-{facts['env']}",
        "run": run,
        "trained_on": facts["plants"],
        "algo": facts["algo"],
        "timesteps": facts["timesteps"],
        "train_wall_time_s": facts["train_wall_time_s"],
        "seeds": seeds,
        "metrics": {"actual": actual},
        "signal": load_objective().signal,
    }
    path = write_json(args.out / args.plant / f"rl-{facts['env']}.json", content)
    if args.json:
        print(json.dumps(json.loads(path.read_text()), indent=2))
    else:
        m = actual["mean"]
        print(
            f"{run} on {args.plant}: cost {m['cost']}, IAE {m['iae']}, SD gap "
            f"{m['sd_gap_deg']}, effort {m['control_effort']} (mean of {len(seeds)} "
            f"held-out seeds); wrote {path}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(cli.run(main))

"""The RL controller: a residual policy on GripperServo-v0, trained with PPO and scored like a PID.

The policy adds a bounded correction (``residual_deg`` at action +/-1) to the output of a fixed
PID, the benchmark's best robust PID by default (``residual: pid``), or to the reference fed
straight to the servo (``residual: reference``); the zero action is that PID, or "command =
reference", exactly. It is trained with stable-baselines3's PPO through
:class:`gripper_env.sb3.NativeVecEnv` (``n_envs`` environments in one compiled call) under
``VecMonitor`` and ``VecNormalize`` (observations and rewards normalised by running statistics;
a servo episode's raw return is about -30 for command = reference and about -1000 for a random
policy, see ``GripperServo-v0``'s docstring), on random grip/un-grip profiles with the
actual-gripper parameters randomised every episode. It never sees the benchmark's profile or its
held-out seeds in training: checkpoints are scored on the Optuna tuning seeds (model selection),
the kept one is evaluated once on the held-out seeds.

The evaluation is every tuner's: the policy's whole episodes on the ``ideal`` model and on the
``actual`` model over the held-out seeds (:func:`gripper_env.envs.rollout.policy_trajectory`,
the same episodes :func:`gripper_env.sim.simulate` runs for a PID), the same metrics,
objective and summary (mean, std, 95 % CI), beside the two baselines it must beat: the residual's
own base (the PID, or command = reference) and command = reference.

Settings: ``configs/tuners/rl_controller.yaml`` (:class:`ControllerSettings`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.config import CONFIG_DIR, load_yaml, validate
from gripper_env.disturbances import Disturbance, load_disturbance
from gripper_env.files import json_ready, write_json
from gripper_env.gains_file import provenance
from gripper_env.objective import load_objective
from gripper_env.pid import PIDGains
from gripper_env.scoring import score_trajectory
from gripper_env.sim import Trajectory, simulate
from tuners import cli
from tuners.evaluation import summarize_runs, with_cost
from tuners.settings import OptunaSettings, load_settings

__all__ = [
    "ControllerSettings",
    "TrainedController",
    "controller_row",
    "evaluate_policy",
    "load_controller_settings",
    "reference_row",
    "train_controller",
]

SERVO = "gripper_env/GripperServo-v0"
_IDEAL = load_disturbance("ideal")
_ON = {"pid": "the PID's output", "reference": "the reference"}


class ControllerSettings(BaseModel):
    """``configs/tuners/rl_controller.yaml``: the residual controller and its training budget."""

    model_config = ConfigDict(extra="forbid")

    residual: Literal["pid", "reference"] = "pid"
    residual_deg: float = Field(20.0, gt=0.0, le=180.0)
    timesteps: int = Field(3_000_000, ge=1)
    quick_timesteps: int = Field(8192, ge=1)
    checkpoints: int = Field(10, ge=1, le=100)
    n_envs: int = Field(32, ge=1)
    n_steps: int = Field(256, ge=1)
    batch_size: int = Field(1024, ge=2)
    n_epochs: int = Field(10, ge=1)
    learning_rate: float = Field(3e-4, gt=0.0)
    gamma: float = Field(0.98, gt=0.0, le=1.0)
    gae_lambda: float = Field(0.95, ge=0.0, le=1.0)
    net_arch: list[int] = [64, 64]
    log_std_init: float = -1.5
    training_reference: str = "random"
    episode_s: float = Field(20.0, gt=0.0)
    randomize: bool = True
    seed: int = 0


def load_controller_settings(path: str | os.PathLike[str] | None = None) -> ControllerSettings:
    """Load and validate the settings (default ``configs/tuners/rl_controller.yaml``)."""
    p = CONFIG_DIR / "tuners" / "rl_controller.yaml" if path is None else path
    return validate(ControllerSettings, load_yaml(p), str(p))


def env_kwargs(inputs: cli.Inputs, base: PIDGains | None, s: ControllerSettings) -> dict[str, Any]:
    """``GripperServo-v0``'s arguments for the controller (without the reference)."""
    _, actual = inputs.settings.options(1)
    kwargs: dict[str, Any] = {
        "plant": inputs.plant.name,
        "disturbance": inputs.disturbance_name,
        "randomize": s.randomize,
        "residual": s.residual,
        "residual_deg": s.residual_deg,
    }
    if s.residual == "pid":
        if base is None:
            raise ValueError("the residual on a PID needs the PID's gains (base)")
        kwargs.update(
            pid_gains=(base.P, base.I, base.D),
            derivative_filter=base.N,
            pid_options={
                "output_limits": actual.output_limits,
                "anti_windup": actual.anti_windup,
                "kb": actual.kb,
                "derivative_on": actual.derivative_on,
                "sign": 1,
            },
        )
    return kwargs


class TrainedController:
    """A trained policy with its observation normalisation: ``policy(obs) -> actions``."""

    def __init__(self, model: Any, vecnormalize: Any) -> None:
        self.model = model
        self.vecnormalize = vecnormalize

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        normalised = self.vecnormalize.normalize_obs(obs)
        return self.model.predict(normalised, deterministic=True)[0]

    def save(self, folder: str | os.PathLike[str]) -> None:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.model.save(folder / "model.zip")
        self.vecnormalize.save(str(folder / "vecnormalize.pkl"))


def _score(traj: Trajectory, disturbance: Disturbance) -> list[dict[str, Any]]:
    """Metrics and cost of every run of a trajectory on ``disturbance``, through the one scoring
    path every tuner's evaluation takes (:func:`gripper_env.scoring.score_trajectory`)."""
    metrics, costs = score_trajectory(traj, load_objective(), disturbance)
    return with_cost(metrics, costs)


def evaluate_policy(
    policy: Callable[[np.ndarray], np.ndarray],
    inputs: cli.Inputs,
    kwargs: dict[str, Any],
    seeds: np.ndarray,
) -> tuple[dict[str, Any], list[dict[str, Any]], Trajectory, Trajectory]:
    """The policy on the ideal model (one run) and on the actual model (one run per seed).

    Returns ``(ideal metrics, actual runs' metrics, ideal trajectory, actual trajectory)``.
    """
    from gripper_env.envs.rollout import policy_trajectory

    ideal_kwargs: dict[str, Any] = {**kwargs, "disturbance": "ideal", "randomize": False}
    ideal = policy_trajectory(policy, [0], reference=inputs.reference, **ideal_kwargs)
    actual = policy_trajectory(policy, seeds, reference=inputs.reference, **kwargs)
    return _score(ideal, _IDEAL)[0], _score(actual, inputs.disturbance), ideal, actual


def cross_model(
    policy: Callable[[np.ndarray], np.ndarray],
    inputs: cli.Inputs,
    kwargs: dict[str, Any],
    base: PIDGains | None,
    seeds: np.ndarray,
) -> dict[str, Any]:
    """The policy (and its base PID's margins) on the paper's other identifications of the
    gripper, in :func:`tuners.evaluation.cross_model`'s shape: a policy trained on one plant,
    run unchanged on the others."""
    from gripper_env.envs.rollout import policy_trajectory
    from gripper_env.plants import load_plant
    from gripper_env.scoring import reachability
    from tuners.evaluation import PAPER_PLANTS, cross_model_entry, worst_case

    if inputs.plant.name not in PAPER_PLANTS:
        return {}
    obj = load_objective()
    per: dict[str, Any] = {}
    for name in PAPER_PLANTS:
        if name == inputs.plant.name:
            continue
        plant = load_plant(name)
        traj = policy_trajectory(policy, seeds, **dict(kwargs, plant=name),
                                 reference=inputs.reference)  # fmt: skip
        m, _ = score_trajectory(traj, obj, inputs.disturbance)
        rb = _robustness(plant, base, inputs.disturbance, m.stable)
        feasible = reachability(plant, inputs.reference, inputs.disturbance).feasible
        per[name] = cross_model_entry(rb, m, feasible)
    return worst_case(per)


def _robustness(
    plant: Any, base: PIDGains | None, disturbance: Disturbance, stable_runs: np.ndarray
) -> dict[str, Any]:
    """The robustness block of a policy's row: the base PID's margins as the loop runs (the
    policy adds a correction bounded by ``residual_deg``, which no linear analysis covers: the
    held-out runs' stability is the check on the whole), or none for the residual on the
    reference (open loop, like ``command = reference``)."""
    from tuners.evaluation import robustness_block

    all_stable = bool(np.all(stable_runs))
    if base is None:
        return {
            "stable": all_stable, "meets_constraints": all_stable, "ms": None, "mt": None,
            "gain_margin_db": None, "phase_margin_deg": None,
            "note": "residual on the reference: no PID, no linear loop to analyse",
        }  # fmt: skip
    block = robustness_block(plant, base, 1, disturbance, load_objective())
    block["stable"] = bool(block["stable"]) and all_stable
    block["note"] = (
        "margins of the base PID; the policy's bounded correction is outside the linear "
        "analysis (every held-out run must stay stable)"
    )
    return block


def reference_row(inputs: cli.Inputs) -> dict[str, Any]:
    """The baseline "command = reference" (the servo commanded the reference, no controller):
    its ``metrics`` on both models and its held-out ``runs``."""
    s = inputs.settings
    seeds = s.seeds.seeds()
    ideal = simulate(inputs.plant, inputs.reference, None, "ideal")
    actual = simulate(inputs.plant, inputs.reference, None, inputs.disturbance, seeds=seeds,
                      randomize=s.randomize)  # fmt: skip
    runs = _score(actual, inputs.disturbance)
    return {
        "metrics": {"ideal": _score(ideal, _IDEAL)[0], "actual": summarize_runs(runs)},
        "runs": runs,
    }


def train_controller(
    inputs: cli.Inputs,
    base: PIDGains | None,
    s: ControllerSettings,
    run_dir: str | os.PathLike[str],
    *,
    timesteps: int | None = None,
    log: Callable[[str], None] = print,
) -> tuple[TrainedController, dict[str, Any]]:
    """Train the residual policy; keep the checkpoint with the lowest mean cost on the Optuna
    tuning seeds (the step profile; never the held-out seeds). Returns it and the training's
    facts (budget, wall time, the checkpoints' tuning costs)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from gripper_env.envs.rollout import policy_trajectory
    from gripper_env.sb3 import NativeVecEnv

    total = s.timesteps if timesteps is None else timesteps
    kwargs = env_kwargs(inputs, base, s)
    train_kwargs = dict(kwargs, reference=s.training_reference)
    if s.training_reference == "random":
        train_kwargs["episode_s"] = s.episode_s
    torch.set_num_threads(1)  # small networks: threads cost more than they give on 2 cores
    venv = VecNormalize(
        VecMonitor(NativeVecEnv(SERVO, num_envs=s.n_envs, **train_kwargs)), gamma=s.gamma
    )
    venv.seed(s.seed)
    model = PPO(
        "MlpPolicy", venv, n_steps=s.n_steps, batch_size=s.batch_size, n_epochs=s.n_epochs,
        learning_rate=s.learning_rate, gamma=s.gamma, gae_lambda=s.gae_lambda, seed=s.seed,
        device="cpu", policy_kwargs={"net_arch": list(s.net_arch), "log_std_init": s.log_std_init},
    )  # fmt: skip
    tuning_seeds = load_settings(OptunaSettings).tuning_seeds.seeds()
    controller = TrainedController(model, venv)
    run_dir = Path(run_dir)

    def tuning_cost() -> float:
        venv.training = False
        traj = policy_trajectory(controller, tuning_seeds, reference=inputs.reference, **kwargs)
        venv.training = True
        return float(np.mean([r["cost"] for r in _score(traj, inputs.disturbance)]))

    history = [(0, tuning_cost())]
    best = history[0][1]
    controller.save(run_dir / "best")
    chunk = max(total // s.checkpoints, s.n_envs * s.n_steps)
    start = time.perf_counter()
    while model.num_timesteps < total:
        model.learn(total_timesteps=min(chunk, total - model.num_timesteps),
                    reset_num_timesteps=False)  # fmt: skip
        cost = tuning_cost()
        history.append((int(model.num_timesteps), cost))
        if cost < best:
            best = cost
            controller.save(run_dir / "best")
        log(
            f"  rl-controller {model.num_timesteps} steps: tuning cost {cost:.4g} (best {best:.4g})"
        )
    wall = time.perf_counter() - start
    trained = int(model.num_timesteps)
    controller.save(run_dir / "last")
    kept = min(history, key=lambda h: h[1])[0]
    model = PPO.load(run_dir / "best" / "model.zip", device="cpu")
    best_venv = VecNormalize.load(str(run_dir / "best" / "vecnormalize.pkl"), venv.venv)
    best_venv.training = False
    period_s = float(train_kwargs.get("control_period_s", 0.020))
    facts = {
        "algo": "ppo",
        "residual": s.residual,
        "residual_deg": s.residual_deg,
        "base_gains": None if base is None else [base.P, base.I, base.D, base.N],
        "timesteps": trained,
        "kept_checkpoint_timesteps": kept,
        "simulated_s": trained * period_s,
        "n_envs": s.n_envs,
        "train_wall_time_s": wall,
        "training_reference": s.training_reference,
        "randomize": s.randomize,
        "tuning_seeds": [int(x) for x in tuning_seeds],
        "history": history,
        "best_tuning_cost": best,
        "settings": s.model_dump(),
    }
    write_json(run_dir / "history.json", facts)
    venv.close()
    return TrainedController(model, best_venv), facts


def controller_row(
    inputs: cli.Inputs,
    base: PIDGains | None,
    *,
    settings: ControllerSettings | None = None,
    out: str | os.PathLike[str] = "results",
    quick: bool = False,
    grip_preset: str | None = "grip-object",
    log: Callable[[str], None] = print,
    command: str | None = None,
) -> dict[str, Any]:
    """Train and evaluate the RL controller on ``inputs``' plant; its benchmark row.

    Parameters
    ----------
    inputs : tuners.cli.Inputs
        Plant, preset, profile and evaluation settings (held-out seeds).
    base : PIDGains or None
        The PID the policy corrects (``residual: pid``): the benchmark's best robust PID.
    settings : ControllerSettings, optional
        Default ``configs/tuners/rl_controller.yaml``.
    out : path
        Results folder: the run goes to ``<out>/rl/controller-<plant>/``, the row's file to
        ``<out>/<plant>/rl-controller.json`` and its response plot beside it.
    quick : bool
        Train ``quick_timesteps`` instead of ``timesteps`` (a smoke run).
    grip_preset : str or None
        The benchmark's grip-onto-an-object scenario preset (``None``: skip it).

    Returns
    -------
    dict
        A benchmark row (:mod:`tuners.benchmark`): ``kind`` ``"rl-controller"``, the base PID's
        ``P``, ``I``, ``D``, ``N`` (``None`` for the residual on the reference), ``robustness``
        (the base PID's margins, see :func:`_robustness`), ``cross_model``, ``metrics``
        {``ideal``, ``actual``}, ``per_seed_iae``, ``per_seed_cost``, ``grip_object``,
        ``episodes`` (20 s episodes simulated in training and checkpoint selection),
        ``wall_time_s`` and ``tuning`` (the budget, and ``baselines``: the base's and command =
        reference's metrics on the same seeds).
    """
    from gripper_env.envs.rollout import policy_trajectory
    from tuners.benchmark import grip_summary

    s = settings or load_controller_settings()
    run_dir = Path(out) / "rl" / f"controller-{inputs.plant.name}"
    t0 = time.perf_counter()
    policy, facts = train_controller(
        inputs, base, s, run_dir, timesteps=s.quick_timesteps if quick else None, log=log
    )
    wall = time.perf_counter() - t0
    kwargs = env_kwargs(inputs, base, s)
    seeds = inputs.settings.seeds.seeds()
    ideal, runs, ideal_traj, actual_traj = evaluate_policy(policy, inputs, kwargs, seeds)
    zero = evaluate_policy(lambda obs: np.zeros((len(obs), 1)), inputs, kwargs, seeds)
    baselines = {
        "base": {"ideal": zero[0], "actual": summarize_runs(zero[1])},
        "command_equals_reference": None,
    }
    grip = None
    if grip_preset is not None:
        traj = policy_trajectory(policy, seeds, **dict(kwargs, disturbance=grip_preset),
                                 reference=inputs.reference)  # fmt: skip
        grip = grip_summary(traj, inputs, grip_preset)
    open_loop = reference_row(inputs)
    baselines["command_equals_reference"] = open_loop["metrics"]
    tuning = {
        **facts,
        "baselines": baselines,
        # paired over the held-out seeds (every controller meets the same draws)
        "vs_base": _paired(runs, zero[1]),
        "vs_command_equals_reference": _paired(runs, open_loop["runs"]),
    }
    episode_steps = round(inputs.reference.duration_s / 0.020)
    row = {
        "kind": "rl-controller",
        "P": None if base is None else base.P,
        "I": None if base is None else base.I,
        "D": None if base is None else base.D,
        "N": None if base is None else base.N,
        "sign": 1,
        "robustness": _robustness(inputs.plant, base, inputs.disturbance,
                                  np.array([r["stable"] for r in runs])),
        "cross_model": cross_model(policy, inputs, kwargs, base, seeds),
        "metrics": {"ideal": ideal, "actual": summarize_runs(runs)},
        "per_seed_iae": [r["iae"] for r in runs],
        "per_seed_cost": [r["cost"] for r in runs],
        "grip_object": grip,
        "episodes": int(facts["timesteps"] // episode_steps
                        + (len(facts["history"])) * len(facts["tuning_seeds"])),
        "wall_time_s": wall,
        "tuning": tuning,
    }  # fmt: skip
    content = {
        "format": "gripper-policy-metrics",
        "plant": inputs.plant.name,
        "tuner": "rl-controller",
        "controller": f"PPO residual on {_ON[s.residual]} ({s.residual_deg:g} deg at |a| = 1)",
        "policy": str(run_dir / "best"),
        **row,
        "evaluation": {
            "profile": inputs.profile_name, "disturbance": inputs.disturbance_name,
            "seeds": [int(x) for x in seeds], "randomize": inputs.settings.randomize,
            "signal": load_objective().signal,
        },
        "provenance": provenance(config={"rl_controller": s.model_dump()}, seed=s.seed,
                                 wall_time_s=wall, command=command),
    }  # fmt: skip
    write_json(Path(out) / inputs.plant.name / "rl-controller.json", json_ready(content))
    _plot(ideal_traj, actual_traj, seeds, Path(out) / inputs.plant.name / "rl-controller.png",
          f"{inputs.plant.name}, RL controller: {content['controller']}")  # fmt: skip
    return row


def _paired(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean per-seed differences ``a - b`` of IAE, cost and overshoot, and the two-sided
    Wilcoxon signed-rank p-value of the IAE differences (as the leaderboard tests costs)."""
    from scipy import stats

    def diff(key: str) -> np.ndarray:
        return np.array([x[key] for x in a], float) - np.array([y[key] for y in b], float)

    d_iae = diff("iae")
    if not np.all(np.isfinite(d_iae)) or np.allclose(d_iae, 0.0):
        p = 1.0 if np.allclose(d_iae, 0.0) else 0.0
    else:
        p = float(stats.wilcoxon(d_iae, zero_method="zsplit").pvalue)
    over = [max(x["grip"]["overshoot_pct"] or 0.0, x["ungrip"]["overshoot_pct"] or 0.0) for x in a]
    over_b = [
        max(y["grip"]["overshoot_pct"] or 0.0, y["ungrip"]["overshoot_pct"] or 0.0) for y in b
    ]
    return {
        "iae_difference": float(d_iae.mean()),
        "iae_relative": float(d_iae.mean() / np.mean([y["iae"] for y in b])),
        "cost_difference": float(diff("cost").mean()),
        "worse_overshoot_difference_pct": float(np.mean(over) - np.mean(over_b)),
        "stall_difference_s": float(diff("stall_s").mean()),
        "iae_p_value": p,
        "iae_better_on_seeds": int(np.sum(d_iae < 0)),
    }


def _plot(ideal: Trajectory, actual: Trajectory, seeds: np.ndarray, path: Path, title: str) -> None:
    """The gains files' response figure, for the policy's runs."""
    from tuners.evaluation import Evaluation
    from tuners.plotting import response_plot

    ev = Evaluation({}, {}, [], {}, [int(x) for x in seeds], ideal, actual)
    response_plot(ev, title, path)

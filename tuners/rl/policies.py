"""Controller policies on the step-by-step environments (``servo``, ``gain-schedule``).

``python -m tuners.rl train --env servo|gain-schedule`` trains PPO or SAC on
``GripperServo-v0`` (the agent commands the servo every 20 ms, or with ``residual`` corrects the
reference or a PID) or ``GripperGainSchedule-v0`` (the agent sets the PID's gains every 20 ms),
through :class:`gripper_env.envs.sb3.NativeVecEnv` under ``VecMonitor`` and ``VecNormalize``
(observations normalised), on random profiles with the preset randomised per episode. The agent
is saved with what rebuilds its environment (:mod:`tuners.rl.agents`) and scored on the held-out
seeds through the one scoring path. The hyperparameters are
``configs/tuners/rl_policy.yaml`` (:class:`PolicySettings`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.io.config import CONFIG_DIR, load_yaml, validate
from tuners import cli
from tuners.evaluation import summarize_runs
from tuners.rl.agents import Agent, save_agent
from tuners.rl.envs import ENV_IDS, progress_callback, require_rl

__all__ = ["PolicySettings", "load_policy_settings", "train_policy"]


class PolicySettings(BaseModel):
    """``configs/tuners/rl_policy.yaml``: budget and hyperparameters per algorithm."""

    model_config = ConfigDict(extra="forbid")

    timesteps: int = Field(200_000, ge=1)
    n_envs: int = Field(16, ge=1)
    gamma: float = Field(0.98, gt=0.0, le=1.0)
    net_arch: list[int] = [64, 64]
    training_reference: str = "random"
    episode_s: float = Field(20.0, gt=0.0)
    randomize: bool = True
    ppo: dict[str, Any] = {"n_steps": 256, "batch_size": 1024, "n_epochs": 10,
                           "learning_rate": 3e-4, "gae_lambda": 0.95}  # fmt: skip
    sac: dict[str, Any] = {"learning_rate": 3e-4, "batch_size": 256, "learning_starts": 1000,
                           "train_freq": 1, "gradient_steps": 1}  # fmt: skip


def load_policy_settings(path: str | os.PathLike[str] | None = None) -> PolicySettings:
    """Load and validate the settings (default ``configs/tuners/rl_policy.yaml``)."""
    p = CONFIG_DIR / "tuners" / "rl_policy.yaml" if path is None else path
    return validate(PolicySettings, load_yaml(p), str(p))


def train_policy(
    inputs: cli.Inputs,
    env: str,
    algo: str,
    s: PolicySettings,
    *,
    seed: int,
    run_dir: str | os.PathLike[str],
    plants: list[str] | None = None,
    timesteps: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train one policy; save it as an agent in ``run_dir``; return its held-out metrics."""
    require_rl()
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from gripper_env.envs.sb3 import NativeVecEnv
    from tuners.rl.controller import evaluate_policy

    if env not in ("servo", "gain-schedule"):
        raise ValueError(f"--env {env}: a controller policy needs servo or gain-schedule")
    names = plants or [inputs.plant.name]
    _, actual = inputs.settings.options(1)
    kwargs: dict[str, Any] = {
        "plant": names if len(names) > 1 else names[0],
        "disturbance": inputs.disturbance_name,
        "randomize": s.randomize,
    }
    if env == "gain-schedule":
        kwargs["pid_options"] = {"output_limits": actual.output_limits,
                                 "anti_windup": actual.anti_windup, "sign": 1}  # fmt: skip
    train_kwargs = dict(kwargs, reference=s.training_reference)
    if s.training_reference == "random":
        train_kwargs["episode_s"] = s.episode_s
    total = s.timesteps if timesteps is None else int(timesteps)
    torch.set_num_threads(1)
    venv = VecNormalize(
        VecMonitor(NativeVecEnv(ENV_IDS[env], num_envs=s.n_envs, **train_kwargs)),
        norm_reward=True, gamma=s.gamma,
    )  # fmt: skip
    venv.seed(seed)
    run_dir = Path(run_dir)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    model = cls(
        "MlpPolicy", venv, gamma=s.gamma, seed=seed, device="cpu", verbose=0,
        tensorboard_log=str(run_dir / "tb"), policy_kwargs={"net_arch": list(s.net_arch)},
        **(s.ppo if algo == "ppo" else s.sac),
    )  # fmt: skip
    start = time.perf_counter()
    model.learn(total, callback=progress_callback(total, f"{algo} on {env} seed {seed}",
                                                  disable=not progress))  # fmt: skip
    wall = time.perf_counter() - start
    venv.training = False
    agent = Agent(model, venv, ENV_IDS[env], kwargs)
    save_agent(agent, run_dir / "agent", {"algo": algo, "seed": seed, "trained_on": names,
                                          "timesteps": int(model.num_timesteps)})  # fmt: skip
    seeds = inputs.settings.seeds.seeds()
    ideal, runs, _, _ = evaluate_policy(agent, inputs, kwargs, seeds, env_id=ENV_IDS[env])
    venv.close()
    return {
        "seed": seed,
        "algo": algo,
        "env_id": ENV_IDS[env],
        "timesteps": int(model.num_timesteps),
        "train_wall_time_s": wall,
        "agent": str(run_dir / "agent"),
        "metrics": {"ideal": ideal, "actual": summarize_runs(runs)},
        "per_seed_cost": [float(r["cost"]) for r in runs],
        "stable_fraction": float(np.mean([r["stable"] for r in runs])),
    }

"""The environments the RL tuners train on, as stable-baselines3 vector environments.

:func:`require_rl` checks the optional ``rl`` extra once, with one line that names it;
:func:`make_vec_env` wraps the environments' native vector form
(:class:`gripper_env.envs.sb3.NativeVecEnv`: one compiled call of the simulation core steps every
environment) under ``VecMonitor``; :class:`LogExactPenalty` is the PID tuner's training reward.
"""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

import numpy as np

from gripper_env.io.config import ConfigError

__all__ = ["ENV_IDS", "LogExactPenalty", "make_vec_env", "progress_callback", "require_rl"]

ENV_IDS = {
    "pid-tune": "gripper_env/GripperPIDTune-v0",
    "gain-schedule": "gripper_env/GripperGainSchedule-v0",
    "servo": "gripper_env/GripperServo-v0",
}

#: The packages of the ``rl`` extra the RL commands import.
_RL_PACKAGES = ("stable_baselines3", "torch")


def require_rl() -> None:
    """Raise :class:`~gripper_env.io.config.ConfigError` (one line, naming the extra) if the
    ``rl`` extra is not installed; register the environments."""
    missing = [name for name in _RL_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        raise ConfigError(
            f"the RL tuners need {', '.join(missing)} (the 'rl' extra): "
            "pip install 'gripper-env[rl]' (scripts/setup.sh installs it)"
        )
    import gripper_env.envs  # noqa: F401 - registers the environments


def make_vec_env(env: str, kwargs: dict[str, Any], n_envs: int, seed: int) -> Any:
    """A stable-baselines3 ``VecEnv`` of ``n_envs`` environments ``env`` (a key of
    :data:`ENV_IDS`): the native vector environment under ``VecMonitor``, seeded."""
    require_rl()
    from stable_baselines3.common.vec_env import VecMonitor

    from gripper_env.envs.sb3 import NativeVecEnv

    vec = VecMonitor(NativeVecEnv(ENV_IDS[env], num_envs=n_envs, **kwargs))
    vec.seed(seed)
    return vec


def LogExactPenalty(venv: Any, penalty: float) -> Any:
    """``GripperPIDTune-v0`` with the PID tuner's training reward,
    ``-log(cost + penalty * violation)``: the environment's own ``reward="log-exact-penalty"``
    (:func:`gripper_env.envs.pid_tune.exact_log_reward`, the default of
    ``GripperPIDTuneRelative-v0``, which says why), computed from each step's ``info`` so that it
    wraps a vector environment of either reward."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from gripper_env.envs.pid_tune import exact_log_reward

    class _LogExactPenalty(VecEnvWrapper):
        def reset(self) -> Any:
            return self.venv.reset()

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            shaped = np.array(
                [
                    exact_log_reward(np.array([i["penalised_cost"]]), np.array([i["feasible"]]),
                                     penalty_jump)[0]
                    if "penalised_cost" in i
                    else -np.log(max(-r, 1e-6))
                    for i, r in zip(infos, rewards, strict=True)
                ]
            )  # fmt: skip
            return obs, shaped.astype(np.float32), dones, infos

    penalty_jump = float(penalty)
    return _LogExactPenalty(venv)


def progress_callback(total: int, desc: str, disable: bool = False) -> Any:
    """A stable-baselines3 callback that shows training steps as a tqdm bar on stderr
    (SB3's own progress bar needs ``rich``; the project has tqdm)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class _Bar(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(
                total=total, desc=desc, unit="step", file=sys.stderr, disable=disable,
                dynamic_ncols=True, mininterval=0.5, initial=min(self.model.num_timesteps, total),
            )  # fmt: skip

        def _on_step(self) -> bool:
            self.bar.update(min(self.model.num_timesteps, total) - self.bar.n)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return _Bar()

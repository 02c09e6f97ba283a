"""stable-baselines3 PPO trains on the environments as registered, with no wrappers added."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import PID_TUNE, SERVO
from stable_baselines3 import PPO

import gripper_env  # noqa: F401


@pytest.mark.parametrize(
    ("env_id", "kwargs", "n_steps", "total"),
    [
        (SERVO, {}, 256, 3072),
        pytest.param(
            PID_TUNE,
            {"plant": ["test2", "test3"], "randomize": True},
            128,
            2048,
            marks=pytest.mark.slow,
        ),
    ],
)
def test_ppo_smoke_training(env_id, kwargs, n_steps, total):
    torch.set_num_threads(1)
    env = gym.make(env_id, **kwargs)
    model = PPO(
        "MlpPolicy", env, n_steps=n_steps, batch_size=64, n_epochs=2, seed=0, device="cpu",
        policy_kwargs={"net_arch": [32, 32]},
    )  # fmt: skip
    model.learn(total_timesteps=total)
    assert model.num_timesteps >= total
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == env.action_space.shape
    _, reward, *_ = env.step(np.clip(action, -1, 1))
    assert np.isfinite(reward)

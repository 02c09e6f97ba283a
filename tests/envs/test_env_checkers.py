"""Gymnasium's and stable-baselines3's environment checkers pass, with warnings as errors."""

import warnings

import gymnasium as gym
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from helpers import ENV_IDS, GAIN_SCHEDULE, RANDOMIZED, SERVO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import gripper_env  # noqa: F401  (registers the ids)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_check_env(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped)  # also renders every declared mode
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3_check_env(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_checkers_with_randomisation_and_context(env_id):
    kwargs = dict(RANDOMIZED)
    if env_id in (SERVO, GAIN_SCHEDULE):
        kwargs["observe_context"] = True
    env = gym.make(env_id, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=True)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


def test_wrapped_env_passes_passive_checker_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for env_id in ENV_IDS:
            env = gym.make(env_id)
            env.reset(seed=0)
            env.step(env.action_space.sample())
            env.close()

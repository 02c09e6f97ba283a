"""Gymnasium's and stable-baselines3's environment checkers pass on every registered id exactly
as ``gym.make`` returns it (with its wrappers), with warnings as errors."""

import contextlib
import warnings

import gymnasium as gym
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from helpers import ENV_IDS, GAIN_SCHEDULE, RANDOMIZED, SERVO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import gripper_env  # noqa: F401  (registers the ids)


@contextlib.contextmanager
def strict():
    """Warnings as errors, except Gymnasium's note that it was handed a wrapped environment (it
    says so for every wrapped env: checking what ``gym.make`` returns is the point here)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        yield


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_checkers_on_env_as_made(env_id):
    env = gym.make(env_id)
    with strict():
        gym_check_env(env)  # also renders every declared mode
        sb3_check_env(env, warn=True)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_checkers_with_randomisation_and_context(env_id):
    kwargs = dict(RANDOMIZED)
    if env_id in (SERVO, GAIN_SCHEDULE):
        kwargs["observe_context"] = True
    env = gym.make(env_id, **kwargs)
    with strict():
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)
    env.close()


@pytest.mark.parametrize(
    "kwargs", [{"residual": "reference"}, {"residual": "pid", "pid_gains": (1.0, 9.0, -0.001)}]
)
def test_checkers_residual_servo(kwargs):
    env = gym.make(SERVO, **kwargs)
    with strict():
        gym_check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)
    env.close()


def test_wrapped_env_passes_passive_checker_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for env_id in ENV_IDS:
            env = gym.make(env_id)
            env.reset(seed=0)
            env.step(env.action_space.sample())
            env.close()

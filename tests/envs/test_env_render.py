"""Rendering: rgb_array images and human mode (under the Agg backend, without warnings)."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from helpers import ENV_IDS

import gripper_env  # noqa: F401


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_rgb_array(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(3):
        *_, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    image = env.render()
    for img in (first, image):
        assert isinstance(img, np.ndarray)
        assert img.dtype == np.uint8
        assert img.ndim == 3 and img.shape[2] == 3
        assert img.shape[0] > 100 and img.shape[1] > 100
    assert img.std() > 0  # something was drawn
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_human_under_agg(env_id):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(env_id, render_mode="human")
        env.reset(seed=0)
        env.step(env.action_space.sample())
        assert env.render() is None
        env.close()

"""A callable agent written for a batch or for one observation is told apart by a probe, and one
that takes neither is refused in one line (hand-worked policies on a two-dimensional space)."""

import gymnasium as gym
import numpy as np
import pytest

from tuners.rl.agents import batch_policy

SPACE = gym.spaces.Box(-np.inf, np.inf, (2,), dtype=np.float32)
OBS = np.array([[1.0, 2.0], [3.0, -4.0], [0.5, 0.5]])


def test_a_batch_policy_is_used_as_it_is():
    def batch(obs):
        return obs[:, :1] - obs[:, 1:]

    policy, written = batch_policy(batch, SPACE, "batch")
    assert written == "batch" and policy is batch


def test_a_one_observation_policy_is_called_row_by_row():
    def one(obs):
        if obs.ndim != 1:
            raise ValueError("cannot reshape array of size 4 into shape (2,)")
        return np.array([obs[0] - obs[1]])

    policy, written = batch_policy(one, SPACE, "one")
    assert written == "one observation"
    assert np.array_equal(policy(OBS), [[-1.0], [7.0], [0.0]])


def test_a_scalar_action_for_one_observation_is_one_action():
    policy, written = batch_policy(lambda o: float(o[0]) if o.ndim == 1 else None, SPACE, "s")
    assert written == "one observation" and policy(OBS).shape == (3, 1)


def test_a_policy_that_takes_neither_is_one_line():
    def broken(obs):
        raise KeyError("no")

    with pytest.raises(ValueError, match="neither a batch policy") as info:
        batch_policy(broken, SPACE, "mod:broken")
    assert "\n" not in str(info.value) and "AGENT mod:broken" in str(info.value)

"""Copies of an environment (pickle, cloudpickle, deepcopy, and what spawned workers receive) are
independent, working environments: same seed and actions, same trajectory as the original."""

import copy
import pickle

import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from helpers import ENV_IDS, PID_TUNE, RANDOMIZED, ROBUST, SERVO

import gripper_env  # noqa: F401

COPIERS = {
    "pickle": lambda env: pickle.loads(pickle.dumps(env)),
    "cloudpickle": lambda env: cloudpickle.loads(cloudpickle.dumps(env)),
    "deepcopy": copy.deepcopy,
}
VARIANTS = [(env_id, {}) for env_id in ENV_IDS] + [
    (SERVO, {"residual": "reference"}),
    (SERVO, {"residual": "pid", "pid_gains": (1.0, 9.0, -0.001)}),
    (SERVO, dict(RANDOMIZED, observe_context=True)),
]


def rollout(env, n_steps, seed=5):
    """Observations, rewards and flags under fixed actions (reset when an episode ends)."""
    rng = np.random.default_rng(0)
    out = [env.reset(seed=seed)[0]]
    for _ in range(n_steps):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        out.append(np.append(obs, [reward, terminated, truncated]))
        if terminated or truncated:
            out.append(env.reset()[0])
    return np.concatenate(out)


@pytest.mark.parametrize("how", COPIERS)
@pytest.mark.parametrize(("env_id", "kwargs"), VARIANTS)
def test_copy_plays_the_original_trajectory(env_id, kwargs, how):
    n = 3 if env_id == PID_TUNE else 60
    fresh = gym.make(env_id, **kwargs)
    expected = rollout(gym.make(env_id, **kwargs), n)
    before_reset = COPIERS[how](fresh)
    np.testing.assert_array_equal(rollout(before_reset, n), expected)
    # a copy taken mid-episode continues from there, independent of the original
    original = gym.make(env_id, **kwargs)
    original.reset(seed=9)
    for _ in range(2 if env_id != PID_TUNE else 0):
        original.step(original.action_space.sample())
    twin = COPIERS[how](original)
    action = np.full(original.action_space.shape, 0.3, np.float32)
    if env_id != PID_TUNE:
        a, b = original.step(action), twin.step(action)
        for x, y in zip(a[:4], b[:4], strict=True):
            np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(rollout(twin, n), expected)
    np.testing.assert_array_equal(rollout(original, n), expected)


@pytest.mark.parametrize("env_id", [*ENV_IDS, ROBUST])
def test_native_vector_env_pickles(env_id):
    def make():
        return gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point",
                            max_episode_steps=4)  # fmt: skip

    def play(envs):
        rng = np.random.default_rng(1)
        out = [envs.reset(seed=2)[0]]
        for _ in range(6):
            obs, rew, term, trunc, _ = envs.step(
                rng.uniform(-1, 1, envs.action_space.shape).astype(np.float32)
            )
            out += [obs.ravel(), rew, term, trunc]
        return np.concatenate([np.ravel(x) for x in out])

    expected = play(make())
    envs = make()
    envs.reset(seed=0)
    np.testing.assert_array_equal(play(pickle.loads(pickle.dumps(envs))), expected)
    np.testing.assert_array_equal(play(envs), expected)


def test_built_envs_in_spawned_workers():
    """SB3's SubprocVecEnv and Gymnasium's AsyncVectorEnv with the spawn start method, handed
    environments built in this process (so the workers receive pickled copies)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    def built(n):
        return [gym.make(SERVO, reference="random", episode_s=0.5) for _ in range(n)]

    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (40, 2, 1)).astype(np.float32)

    def play_sb3(vec):
        vec.seed(3)
        out = [vec.reset()]
        for a in actions:
            obs, rew, done, infos = vec.step(a)
            term = [i.get("terminal_observation", np.zeros(6, np.float32)) for i in infos]
            # (DummyVecEnv keeps rewards in float32, SubprocVecEnv in float64)
            out += [obs.ravel(), rew.astype(np.float32), done, np.concatenate(term)]
        vec.close()
        return np.concatenate([np.ravel(x) for x in out])

    spawned = play_sb3(SubprocVecEnv([lambda e=e: e for e in built(2)], start_method="spawn"))
    local = play_sb3(DummyVecEnv([lambda e=e: e for e in built(2)]))
    np.testing.assert_array_equal(spawned, local)
    assert np.any(spawned != 0)

    def play_gym(vec):
        out = [vec.reset(seed=3)[0]]
        for a in actions:
            obs, rew, term, trunc, _ = vec.step(a)
            out += [obs.ravel(), rew, term, trunc]
        vec.close()
        return np.concatenate([np.ravel(x) for x in out])

    spawned = play_gym(gym.vector.AsyncVectorEnv([lambda e=e: e for e in built(2)],
                                                 context="spawn"))  # fmt: skip
    local = play_gym(gym.vector.SyncVectorEnv([lambda e=e: e for e in built(2)]))
    np.testing.assert_array_equal(spawned, local)

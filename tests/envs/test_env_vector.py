"""The native vector environments equal N single environments with the same seeds."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import (
    GAIN_SCHEDULE,
    PID_TUNE,
    RANDOMIZED,
    ROBUST,
    SERVO,
    assert_same_info,
    step_native_and_singles,
)

import gripper_env  # noqa: F401
from gripper_env.envs import kernels


def compare(env_id, n_envs, n_steps, seed, **kwargs):
    # an import of rl_zoo3 in this process replaces TimeLimit, which then adds infos of its own
    assert gym.wrappers.TimeLimit.__module__.startswith("gymnasium."), "TimeLimit is patched"
    native = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                          **kwargs)  # fmt: skip
    sync = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="sync", **kwargs)
    assert isinstance(native, gym.vector.VectorEnv)
    assert not isinstance(native, gym.vector.SyncVectorEnv)
    assert native.observation_space == sync.observation_space
    assert native.action_space == sync.action_space
    obs_n, info_n = native.reset(seed=seed)
    obs_s, info_s = sync.reset(seed=seed)
    np.testing.assert_array_equal(obs_n, obs_s)
    assert set(info_n) == {"plant", "_plant", "reference", "_reference", "noise_seed",
                           "_noise_seed"}  # fmt: skip
    assert_same_info(info_n, info_s)
    rng = np.random.default_rng(seed)
    resets = 0
    for _ in range(n_steps):
        actions = rng.uniform(-1.1, 1.1, native.action_space.shape).astype(np.float32)
        out_n = native.step(actions)
        out_s = sync.step(actions)
        for a, b in zip(out_n[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(a, b)
        assert_same_info(out_n[4], out_s[4])
        resets += int(np.sum(out_n[2] | out_n[3]))
    native.close()
    sync.close()
    return resets


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        (SERVO, {}),
        (GAIN_SCHEDULE, {}),
        (SERVO, {"residual": "reference"}),
        (SERVO, {"residual": "pid", "pid_gains": (1.0, 9.0, -0.001)}),
    ],
)
def test_vector_equals_single_envs_across_autoreset(env_id, kwargs):
    # a 30-step time limit forces every environment through an autoreset
    resets = compare(env_id, 5, 75, seed=11, max_episode_steps=30, **kwargs)
    assert resets >= 10


@pytest.mark.parametrize("env_id", [SERVO, GAIN_SCHEDULE])
def test_vector_equals_single_envs_randomized(env_id):
    # 1 s random references: episodes of 50 steps end by themselves (truncation)
    resets = compare(env_id, 4, 110, seed=3, observe_context=True, **RANDOMIZED)
    assert resets >= 8


@pytest.mark.parametrize(
    "kwargs",
    [{"episode_s": 4.0}, {"episode_s": 6.0, "max_episode_steps": 160},
     {"residual": "reference", "episode_s": 3.0}],
)  # fmt: skip
def test_vector_robust_equals_single_envs_with_its_costs(kwargs):
    """GripperServoRobust-v0's vector form: observations, rewards, ends and every info (the
    swing and stop costs, margin_episode, the reset infos) equal SyncVectorEnv's through
    autoresets, under actions that swing the jaw on holds and drive it into the stops."""
    n = 6
    native = gym.make_vec(ROBUST, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec(ROBUST, num_envs=n, vectorization_mode="sync", **kwargs)
    obs_n, info_n = native.reset(seed=3)
    obs_s, info_s = sync.reset(seed=3)
    np.testing.assert_array_equal(obs_n, obs_s)
    assert_same_info(info_n, info_s)
    assert "margin_episode" in info_n
    rng = np.random.default_rng(0)
    sums = {"cost_swing": 0.0, "cost_stop": 0.0}
    margin_rows = set()
    for k in range(400):
        actions = rng.uniform(-1.1, 1.1, native.action_space.shape).astype(np.float32)
        if k % 50 < 25:  # a square wave of 6 steps' half period: the jaw swings
            actions[:] = 0.9 * np.sign(np.sin(k / 3.0))
        out_n, out_s = native.step(actions), sync.step(actions)
        for a, b in zip(out_n[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(a, b)
        assert_same_info(out_n[4], out_s[4])
        for key in sums:
            sums[key] += float(np.sum(out_n[4].get(key, 0.0)))
        margin_rows |= set(np.flatnonzero(out_n[4].get("margin_episode", [])).tolist())
    assert sums["cost_swing"] > 0 and sums["cost_stop"] > 0  # both costs were exercised
    assert margin_rows  # some episodes had their gain raised
    native.close()
    sync.close()


def test_vector_pid_tune_equals_single_envs():
    resets = compare(PID_TUNE, 3, 4, seed=5, **RANDOMIZED)
    assert resets == 6


def test_vector_parallel_batch_equals_serial():
    """The parallel kernel (forced on a batch of three chunks of rows, the last partial) gives
    the same rows as single envs."""
    n = 37
    native = gym.make_vec(SERVO, num_envs=n, vectorization_mode="vector_entry_point",
                          max_episode_steps=8)  # fmt: skip
    native.unwrapped.set_parallel(True)
    assert native.unwrapped._batch._kernel is kernels.step_parallel
    obs, _ = native.reset(seed=100)
    singles = [gym.make(SERVO, max_episode_steps=8) for _ in range(n)]
    single_obs = [e.reset(seed=100 + i)[0] for i, e in enumerate(singles)]
    np.testing.assert_array_equal(obs, np.stack(single_obs))
    rng = np.random.default_rng(0)
    pending = np.zeros(n, dtype=bool)
    for _ in range(12):
        actions = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        pending = step_native_and_singles(native, singles, actions, pending)


def test_vector_reset_mask_and_seed_list():
    envs = gym.make_vec(SERVO, num_envs=3, vectorization_mode="vector_entry_point",
                        reference="random", episode_s=2.0)  # fmt: skip
    obs_a, _ = envs.reset(seed=[1, 2, 3])
    envs.step(np.zeros((3, 1), np.float32))
    obs_b, _ = envs.reset(seed=[None, 2, None], options={"reset_mask": np.array([0, 1, 0], bool)})
    np.testing.assert_array_equal(obs_a[1], obs_b[1])
    with pytest.raises(ValueError, match="num_envs"):
        envs.reset(seed=[1, 2])


def test_vector_bad_actions():
    envs = gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point")
    clean = gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    clean.reset(seed=0)
    with pytest.raises(ValueError, match=r"finite.*environment 1"):
        envs.step(np.array([[0.0], [np.nan]], np.float32))
    with pytest.raises(ValueError, match="finite"):
        envs.step([[np.inf], [0.5]])
    # a refused step changes nothing: the next one equals that of environments that never saw it
    good = np.array([[0.3], [-0.2]], np.float32)
    for a, b in zip(envs.step(good)[:4], clean.step(good)[:4], strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((3, 1), np.float32))


@pytest.mark.parametrize("env_id", [SERVO, PID_TUNE])
def test_vector_renders_the_chosen_envs(env_id):
    """render() gives the frames of render_envs, equal to the single environments' frames."""
    kwargs = {"reference": "random", "episode_s": 1.0}
    native = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point",
                          render_mode="rgb_array", render_envs=[2, 0], **kwargs)  # fmt: skip
    singles = [gym.make(env_id, render_mode="rgb_array", **kwargs) for _ in range(3)]
    assert native.metadata["render_fps"] == singles[0].metadata["render_fps"]
    native.reset(seed=4)
    for i, env in enumerate(singles):
        env.reset(seed=4 + i)
    rng = np.random.default_rng(0)
    for step in range(4):
        actions = rng.uniform(-1, 1, native.action_space.shape).astype(np.float32)
        native.step(actions)
        if env_id == PID_TUNE and step % 2:  # the vector env's autoreset step
            for env in singles:
                env.reset()
        else:
            for i, env in enumerate(singles):
                env.step(actions[i])
        frames = native.render()
        assert len(frames) == 2
        np.testing.assert_array_equal(frames[0], singles[2].render())
        np.testing.assert_array_equal(frames[1], singles[0].render())
    native.close()
    with pytest.raises(ValueError, match="'render_envs'"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                     render_mode="rgb_array", render_envs=[2])  # fmt: skip

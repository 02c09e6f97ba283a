"""gripper_env.envs.sb3.NativeVecEnv: stable-baselines3 on the native vector environments, step for
step equal to a DummyVecEnv of gym.make environments with the same seeds."""

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor, VecNormalize

import gripper_env  # noqa: F401
from gripper_env.envs.sb3 import NativeVecEnv

SERVO = "gripper_env/GripperServo-v0"
PID_TUNE = "gripper_env/GripperPIDTune-v0"
GAIN_SCHEDULE = "gripper_env/GripperGainSchedule-v0"
ROBUST = "gripper_env/GripperServoRobust-v0"


def dummy(env_id, n, **kwargs):
    return DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)])


def assert_same_infos(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.keys() == y.keys()
        for key in x:
            if isinstance(x[key], dict):
                assert_same_infos([x[key]], [y[key]])
            else:
                np.testing.assert_array_equal(x[key], y[key])


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        (SERVO, {"max_episode_steps": 7, "reference": "random", "episode_s": 0.1}),
        (GAIN_SCHEDULE, {"max_episode_steps": 5}),
        (SERVO, {"max_episode_steps": 6, "residual": "reference"}),
        (PID_TUNE, {"plant": ["test2", "test3"], "randomize": True}),
        (ROBUST, {"max_episode_steps": 7, "episode_s": 0.5}),
    ],
)
def test_steps_equal_dummy_vec_env(env_id, kwargs):
    """Observations, rewards, dones and infos (terminal observation, time-limit flag, every
    metric) equal DummyVecEnv's through several autoresets; reset infos too."""
    n = 3
    native = NativeVecEnv(env_id, num_envs=n, **kwargs)
    reference = dummy(env_id, n, **kwargs)
    assert native.observation_space == reference.observation_space
    assert native.action_space == reference.action_space
    for venv in (native, reference):
        venv.seed(11)
    np.testing.assert_array_equal(native.reset(), reference.reset())
    assert_same_infos(native.reset_infos, reference.reset_infos)
    rng = np.random.default_rng(0)
    dones = 0
    for _ in range(4 if env_id == PID_TUNE else 16):
        actions = rng.uniform(-1, 1, (n, *native.action_space.shape)).astype(np.float32)
        a, b = native.step(actions), reference.step(actions)
        for x, y in zip(a[:3], b[:3], strict=True):
            np.testing.assert_array_equal(x, y)
            assert x.dtype == y.dtype
        assert_same_infos(a[3], b[3])
        assert_same_infos(native.reset_infos, reference.reset_infos)
        dones += int(a[2].sum())
    assert dones >= 2 * n


def ppo(venv, seed=3):
    torch.set_num_threads(1)
    return PPO(
        "MlpPolicy", venv, n_steps=16, batch_size=24, n_epochs=2, seed=seed, device="cpu",
        policy_kwargs={"net_arch": [16, 16]},
    )  # fmt: skip


@pytest.mark.parametrize("wrap", ["plain", "monitor+normalize"])
def test_ppo_equals_ppo_on_dummy_vec_env(wrap):
    """PPO through the adapter is PPO on a DummyVecEnv of the same seeds, step for step: same
    rollouts (episodes end and reset inside them) and bit-identical weights after training."""
    kwargs = {"residual": "reference", "max_episode_steps": 10}

    def wrapped(venv):
        return venv if wrap == "plain" else VecNormalize(VecMonitor(venv), gamma=0.99)

    models = []
    for venv in (NativeVecEnv(SERVO, num_envs=3, **kwargs), dummy(SERVO, 3, **kwargs)):
        model = ppo(wrapped(venv))
        model.learn(total_timesteps=3 * 16 * 3)
        models.append(model)
    a, b = models
    np.testing.assert_array_equal(a.rollout_buffer.observations, b.rollout_buffer.observations)
    np.testing.assert_array_equal(a.rollout_buffer.rewards, b.rollout_buffer.rewards)
    np.testing.assert_array_equal(a.rollout_buffer.episode_starts, b.rollout_buffer.episode_starts)
    assert a.rollout_buffer.episode_starts.sum() > 0
    for p, q in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert torch.equal(p, q)
    if wrap != "plain":
        np.testing.assert_array_equal(a.get_env().obs_rms.mean, b.get_env().obs_rms.mean)
        assert len(a.ep_info_buffer) == len(b.ep_info_buffer) > 0


def test_ppo_learns_through_the_adapter():
    """PPO picks far better PID gains after 1024 GripperPIDTune episodes through the adapter:
    the deterministic policy's cost on held-out episodes falls at least fourfold."""
    torch.set_num_threads(1)
    venv = NativeVecEnv(PID_TUNE, num_envs=32, plant="test2", disturbance="ideal")
    model = PPO(
        "MlpPolicy", venv, n_steps=4, batch_size=64, n_epochs=10, gamma=0.0, gae_lambda=0.0,
        learning_rate=3e-3, seed=0, device="cpu", policy_kwargs={"net_arch": [16]},
    )  # fmt: skip

    def cost():
        env = NativeVecEnv(PID_TUNE, num_envs=16, plant="test2", disturbance="ideal")
        env.seed(1000)
        obs = env.reset()
        actions, _ = model.predict(obs, deterministic=True)
        return -float(env.step(actions)[1].mean())

    before = cost()
    model.learn(total_timesteps=1024)
    after = cost()
    assert after < before / 4, (before, after)


def test_bad_inputs():
    with pytest.raises(ValueError, match="num_envs"):
        NativeVecEnv(SERVO)
    with pytest.raises(TypeError, match="DummyVecEnv"):
        NativeVecEnv(gym.make_vec(SERVO, num_envs=2, vectorization_mode="sync"))
    with pytest.raises(ValueError, match="'plant'"):
        NativeVecEnv(SERVO, num_envs=2, plant="test9")

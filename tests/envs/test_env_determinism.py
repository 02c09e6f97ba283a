"""Same seed, identical trajectories; and the environments agree with the simulation core."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import GAIN_SCHEDULE, PID_TUNE, RANDOMIZED, SERVO, signed_log_gains

import gripper_env  # noqa: F401
from gripper_env.sim import simulate


def rollout(env, seed, n_steps, action_seed=0):
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for _ in range(n_steps):
        action = rng.uniform(-1.2, 1.2, env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        out.append(np.append(obs, [reward, terminated, truncated]))
        if terminated or truncated:
            obs, _ = env.reset()
            out.append(obs)
    return out


@pytest.mark.parametrize("env_id", [SERVO, GAIN_SCHEDULE, PID_TUNE])
@pytest.mark.parametrize("kwargs", [{}, RANDOMIZED], ids=["default", "randomized"])
def test_same_seed_same_trajectory(env_id, kwargs):
    n = 4 if env_id == PID_TUNE else 120
    a = rollout(gym.make(env_id, **kwargs), seed=7, n_steps=n)
    b = rollout(gym.make(env_id, **kwargs), seed=7, n_steps=n)
    c = rollout(gym.make(env_id, **kwargs), seed=8, n_steps=n)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=False))


def test_servo_equals_open_loop_simulation():
    """Holding the servo command constant is the core's open-loop run of that command."""
    env = gym.make(SERVO)
    _, info = env.reset(seed=3)
    action = np.array([-0.5], dtype=np.float32)  # 45 deg over the [0, 180] command range
    positions = []
    for _ in range(50):
        obs, *_ = env.step(action)
        positions.append(obs[0] * 35.5 + 56.5)
    command = np.full(1000, 45.0)
    traj = simulate("test2", command, gains=None, disturbance="actual",
                    seeds=info["noise_seed"], y0_deg=92.0)  # fmt: skip
    np.testing.assert_allclose(positions, traj.y[0, 19::20][:50], rtol=0, atol=1e-4)


def test_gain_schedule_with_constant_gains_equals_closed_loop_simulation():
    action = np.array([0.6, 0.7, -0.3])
    env = gym.make(GAIN_SCHEDULE)
    _, info = env.reset(seed=5)
    positions = []
    for _ in range(1000):
        obs, *_ = env.step(action.astype(np.float32))
        positions.append(obs[0] * 35.5 + 56.5)
    gains = signed_log_gains(action.astype(np.float32))
    traj = simulate("test2", "step", gains=[gains], disturbance="actual",
                    seeds=info["noise_seed"])  # fmt: skip
    np.testing.assert_allclose(positions, traj.y[0, 19::20], rtol=0, atol=1e-4)

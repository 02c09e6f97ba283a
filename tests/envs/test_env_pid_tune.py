"""GripperPIDTune's reward is minus the shared objective, checked through simulate() directly."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import PID_TUNE, signed_log_gains

import gripper_env  # noqa: F401
from gripper_env.envs.spaces import action_to_gains, gains_to_action
from gripper_env.metrics import compute_metrics
from gripper_env.objective import load_objective
from gripper_env.paper import PID_GAINS as PAPER_GAINS
from gripper_env.simulation import simulate


@pytest.mark.parametrize("action", [[0.668, 0.752, -0.347], [-0.2, 0.9, 0.0], [1.0, 1.0, 1.0]])
def test_reward_is_minus_objective_cost_of_simulate(action):
    env = gym.make(PID_TUNE)
    _, info0 = env.reset(seed=21)
    action = np.asarray(action, np.float32)
    _, reward, terminated, _, info = env.step(action)
    assert terminated
    traj = simulate(
        "test2", "step", gains=[signed_log_gains(action)], disturbance="actual",
        seeds=info0["noise_seed"],
    )  # fmt: skip
    cost = load_objective().cost(compute_metrics(traj), duration_s=20.0)[0]
    assert reward == pytest.approx(-cost, rel=1e-12, abs=1e-12)
    assert info["cost"] == pytest.approx(cost, rel=1e-12)
    assert info["iae"] == pytest.approx(compute_metrics(traj).run["iae"][0], rel=1e-12)
    for key in ("grip", "ungrip", "sd_gap_deg", "control_effort", "stable", "gains", "cost_terms"):
        assert key in info


def test_reward_with_randomised_episode_matches_simulate():
    env = gym.make(PID_TUNE, plant=["test1", "test3"], randomize=True, reference="random",
                   episode_s=5.0)  # fmt: skip
    _, info0 = env.reset(seed=2)
    ep = env.unwrapped._episode
    action = np.array([0.5, 0.6, -0.2], np.float32)
    _, reward, *_ = env.step(action)
    traj = simulate(
        info0["plant"], ep.reference, gains=[signed_log_gains(action)], disturbance=ep.disturbance,
        seeds=info0["noise_seed"],
    )  # fmt: skip
    cost = load_objective().cost(compute_metrics(traj), duration_s=ep.reference.duration_s)[0]
    assert reward == pytest.approx(-cost, rel=1e-12)


def test_paper_tuned_gains_beat_untuned_on_ideal_test2():
    env = gym.make(PID_TUNE, disturbance="ideal")
    rewards = {}
    for name in ("tuned_tf", "untuned_tf"):
        env.reset(seed=0)
        rewards[name] = env.step(gains_to_action(PAPER_GAINS[name]).astype(np.float32))[1]
    assert rewards["tuned_tf"] > rewards["untuned_tf"]


def test_diverging_gains_get_the_unstable_cost():
    env = gym.make(PID_TUNE, disturbance="ideal", plant="test4")
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([-1.0, -1.0, -1.0], np.float32))
    assert not info["stable"]
    assert reward == -load_objective().unstable_cost


def test_gain_map_round_trip_and_sign():
    gains = np.array([[1.0, 9.0, -0.001], [-0.5, -3.6, 0.000186], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(action_to_gains(gains_to_action(gains)), gains, rtol=1e-12)
    np.testing.assert_allclose(action_to_gains([1, -1, 1]), [10.0, -50.0, 0.1])
    np.testing.assert_allclose(action_to_gains([0.5, 0.5, 0.5], scaling="linear"),
                               [5.0, 25.0, 0.05])  # fmt: skip

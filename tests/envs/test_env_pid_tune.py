"""GripperPIDTune's reward is minus the shared objective (penalised when the gains miss the
robustness constraints), checked through simulate(), the metrics and the loop analysis directly."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import PID_TUNE, signed_log_gains

import gripper_env  # noqa: F401
from gripper_env.envs.spaces import action_to_gains, gains_to_action
from gripper_env.evaluation.metrics import compute_metrics
from gripper_env.evaluation.objective import load_objective
from gripper_env.evaluation.stability import stability_report
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import load_plant
from gripper_env.paper import PID_GAINS as PAPER_GAINS
from gripper_env.sim import simulate

TEST2 = load_plant("test2")
ACTUAL = load_disturbance("actual")


def _expected_reward(plant, gains, traj, disturbance, preset="actual"):
    """Minus the objective's cost on the true angle with the preset's friction settling band,
    plus the penalty if the gains miss the constraints (stability_report, not the env)."""
    obj = load_objective()
    band = obj.settling_band_deg(load_disturbance(preset))
    metrics = compute_metrics(traj, "true", settling_band_deg=band)
    cost = obj.cost(metrics, traj.reference.duration_s)[0]
    report = stability_report(plant, PIDGains(*gains), disturbance=disturbance)
    feasible = report.meets(obj.constraints.ms_max, obj.constraints.gm_min_db)
    return cost, feasible, -(cost if feasible else cost + obj.infeasible_penalty)


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
    cost, feasible, expected = _expected_reward(TEST2, signed_log_gains(action), traj, ACTUAL)
    assert info["cost"] == pytest.approx(cost, rel=1e-12)
    assert info["feasible"] == feasible
    if feasible:
        assert reward == pytest.approx(expected, rel=1e-12, abs=1e-12)
    else:  # at least the penalty, more the further from feasible
        assert reward <= expected
    assert info["iae"] == pytest.approx(compute_metrics(traj, "true").run["iae"][0], rel=1e-12)
    for key in ("grip", "ungrip", "stall_s", "servo_effort_deg", "stable", "gains", "cost_terms",
                "robustness"):  # fmt: skip
        assert key in info


def test_infeasible_gains_are_clearly_worse():
    """The old Optuna winner (Ms 10.6 with the hold) scores at least the penalty worse than a
    robust PI (AMIGO)."""
    gain_max = (10.0, 100.0, 0.1)
    env = gym.make(PID_TUNE, gain_max=gain_max)
    rewards, infos = [], []
    for gains in ((0.3712, 98.64, -0.002567), (2.43, 39.0, 0.0)):
        env.reset(seed=3)
        action = gains_to_action(gains, gain_max).astype(np.float32)
        _, r, _, _, info = env.step(action)
        rewards.append(r)
        infos.append(info)
    assert not infos[0]["feasible"] and infos[1]["feasible"]
    assert infos[0]["robustness"]["ms"] > 10
    assert rewards[0] < rewards[1] - load_objective().infeasible_penalty


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
    cost, feasible, expected = _expected_reward(
        load_plant(info0["plant"]), signed_log_gains(action), traj, ep.disturbance
    )
    assert feasible == (reward >= -cost - 1e-9)
    if feasible:
        assert reward == pytest.approx(expected, rel=1e-12)


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
    assert not info["stable"] and not info["feasible"]
    obj = load_objective()
    assert info["cost"] == obj.unstable_cost
    assert reward <= -(obj.unstable_cost + obj.infeasible_penalty)


def test_gain_map_round_trip_and_sign():
    gains = np.array([[1.0, 9.0, -0.001], [-0.5, -3.6, 0.000186], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(action_to_gains(gains_to_action(gains)), gains, rtol=1e-12)
    np.testing.assert_allclose(action_to_gains([1, -1, 1]), [10.0, -50.0, 0.1])
    np.testing.assert_allclose(action_to_gains([0.5, 0.5, 0.5], scaling="linear"),
                               [5.0, 25.0, 0.05])  # fmt: skip


def test_the_relative_gain_map_centres_on_a_design():
    """``gain_scaling="relative"``: the zero action is the design, a unit action a decade, and
    the inverse map gives the action back."""
    import gymnasium as gym

    from gripper_env.envs.spaces import action_to_gains, gains_to_action

    center = (2.4, 39.0, 0.001)
    env = gym.make("gripper_env/GripperPIDTune-v0", gain_scaling="relative", gain_center=center,
                   gain_decades=1.0, gain_max=(1.0, 1.0, 0.02))  # fmt: skip
    env.reset(seed=0)
    info = env.step(np.zeros(3, np.float32))[4]
    assert (info["gains"]["P"], info["gains"]["I"], info["gains"]["D"]) == pytest.approx(center)
    a = np.array([[1.0, -0.5, -1.0]])
    g = action_to_gains(a, (1.0, 1.0, 0.02), "relative", center, 1.0)
    assert g[0] == pytest.approx([24.0, 39.0 / 10**0.5, 0.001 - 0.02])
    assert gains_to_action(g, (1.0, 1.0, 0.02), "relative", center, 1.0) == pytest.approx(a)


@pytest.mark.parametrize(
    "kwargs, match",
    [({"gain_scaling": "relative"}, "gain_center"),
     ({"gain_scaling": "relative", "gain_center": (0.0, 1.0, 0.0)}, "nonzero"),
     ({"gain_scaling": "relative", "gain_center": (1.0, 1.0, 0.0), "gain_decades": 9}, "decades")],
)  # fmt: skip
def test_a_bad_relative_map_is_one_line(kwargs, match):
    import gymnasium as gym

    from gripper_env.io.config import ConfigError

    with pytest.raises(ConfigError, match=match):
        gym.make("gripper_env/GripperPIDTune-v0", **kwargs)

"""The limit of a tracking episode's return: the linear program of the reward."""

import gymnasium as gym
import numpy as np
import pytest

import gripper_env  # noqa: F401
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from gripper_env.model.references import random_profile
from tuners.benchmark.limit import least_iae
from tuners.rl.limits import reward_limit

TEST2 = load_plant("test2")
REF = random_profile(3, 2.0, 1e-3)  # 0.5-1.5 s open, then a move: a short LP
# the linear loop the program describes: the transfer function, the 20 ms hold, 0-180 deg
HOLD = {"extends": "ideal", "command": {"range_deg": [0.0, 180.0], "refresh_period_s": 0.02}}


def _replay(commands, delay_s=0.0, reference=REF):
    """The return of the servo environment commanded ``commands`` (one per 20 ms frame)."""
    dist = dict(HOLD, sensor={"delay_s": delay_s})
    env = gym.make("gripper_env/GripperServo-v0", disturbance=dist, reference=reference,
                   max_episode_steps=None)  # fmt: skip
    env.reset(seed=0)
    total, done, j = 0.0, False, 0
    while not done:
        action = np.array([(commands[j] - 90.0) / 90.0], np.float32)
        _, r, te, tr, _ = env.step(action)
        total, j, done = total + r, j + 1, te or tr
    return total


def test_with_no_overshoot_or_chatter_weight_it_is_the_least_iae():
    lp = reward_limit(TEST2, REF.values_deg, overshoot_weight=0.0, chatter_weight=0.0)
    assert lp.iae == pytest.approx(least_iae(TEST2, REF, load_disturbance("actual")).iae, rel=1e-6)
    assert lp.cost == pytest.approx(lp.iae / (20 * 35.5 * 1e-3), rel=1e-9)


@pytest.mark.parametrize("delay_ms", [0, 20])
def test_its_commands_replayed_through_the_environment_return_its_optimum(delay_ms):
    """Through GripperServo-v0 on the linear loop (the env's own reward: tracking of the measured
    angle, overshoot, the servo command's changes), the optimal commands return minus the
    program's cost, to the float32 rounding of the actions."""
    lp = reward_limit(TEST2, REF.values_deg, delay_steps=delay_ms)
    assert _replay(lp.commands_deg, delay_ms * 1e-3) == pytest.approx(-lp.cost, abs=1e-4)


def test_no_controller_on_the_linear_loop_beats_it():
    """Command = reference and a PID, through the same environment, return less."""
    lp = reward_limit(TEST2, REF.values_deg)
    frames = REF.values_deg[::20]
    assert _replay(frames) < -lp.cost
    env = gym.make("gripper_env/GripperServo-v0", disturbance=HOLD, reference=REF,
                   residual="pid", pid_gains=(3.43, 67.5, -0.0087),
                   pid_options={"output_limits": (0.0, 180.0)})  # fmt: skip
    env.reset(seed=0)
    total, done = 0.0, False
    while not done:
        _, r, te, tr, _ = env.step(np.zeros(1, np.float32))
        total, done = total + r, te or tr
    assert total < -lp.cost


def test_an_unbounded_command_range_is_refused():
    with pytest.raises(ValueError, match="bounded command range"):
        reward_limit(TEST2, REF.values_deg, command_range_deg=(-np.inf, np.inf))

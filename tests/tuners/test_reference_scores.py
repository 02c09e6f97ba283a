"""Reference scores: the policies run through the environment as documented."""

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.sim import simulate
from tuners.rl import reference_scores as rs

PID = PIDGains(3.43, 67.5, -0.0087)


def test_the_pid_through_the_servo_environment_is_the_pid_of_the_core():
    """The "best PID" row of GripperServo-v0 runs the PID inside the environment: its jaw is
    the simulation core's closed loop with those gains."""
    from gripper_env.envs.rollout import policy_trajectory

    policy, kwargs = rs._pid_policy("gripper_env/GripperServo-v0", {}, PID)
    traj = policy_trajectory(policy, [0], reference="step", **kwargs)
    core = simulate(
        "test2",
        "step",
        [PID.as_array()],
        "actual",
        seeds=[0],
        pid_options=PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping"),
    )
    np.testing.assert_allclose(traj.y_true[0], core.y_true[0], atol=1e-9)


def test_the_pid_gains_through_the_tuning_environment_are_the_gains():
    import gymnasium as gym

    policy, kwargs = rs._pid_policy("gripper_env/GripperPIDTune-v0", {}, PID)
    env = gym.make("gripper_env/GripperPIDTune-v0", **kwargs)
    obs, _ = env.reset(seed=0)
    info = env.step(policy(obs[None, :])[0].astype(np.float32))[4]
    assert [info["gains"][k] for k in "PID"] == pytest.approx([PID.P, PID.I, PID.D], rel=1e-5)


def test_command_equals_reference_commands_the_reference():
    import gymnasium as gym

    env = gym.make("gripper_env/GripperServo-v0")
    policy = rs._command_equals_reference("gripper_env/GripperServo-v0", {})
    obs, _ = env.reset(seed=0)
    for _ in range(90):  # through the grip step at 1 s
        action = policy(obs[None, :])[0]
        obs, *_ = env.step(action.astype(np.float32))
    # after the step the command is the reference, 21 deg on the 0-180 deg command range
    assert action[0] == pytest.approx((21.0 - 90.0) / 90.0)
    assert float(obs[1]) == pytest.approx(-1.0)  # the reference is the jaw range's closed end
    assert abs(float(obs[1]) - float(obs[0])) < 0.05  # and the jaw has followed it

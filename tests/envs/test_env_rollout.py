"""policy_trajectory: a policy's whole episodes as a Trajectory, equal to simulate()'s runs."""

import subprocess
import sys

import numpy as np
import pytest

from gripper_env.envs.rollout import policy_trajectory
from gripper_env.model.pid import PIDOptions
from gripper_env.sim import simulate

SEEDS = [100000, 100001, 100002]
FIELDS = ("r", "u", "y", "y_true", "stable", "saturated_s", "contact_s", "stall_s",
          "force_proxy", "servo_effort_deg")  # fmt: skip
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")


def zero(obs):
    return np.zeros((len(obs), 1))


def assert_same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_zero_reference_residual_is_simulate_open_loop():
    """Command = reference, seed by seed: the randomised disturbance draw, the noise, every
    counter of the core."""
    traj = policy_trajectory(zero, SEEDS, residual="reference", randomize=True)
    assert_same(traj, simulate("test2", "step", None, "actual", seeds=SEEDS, randomize=True))
    assert traj.y.shape == (3, 20000) and np.all(np.isfinite(traj.y))


def test_zero_pid_residual_is_simulate_closed_loop():
    gains = (2.4, 39.0, 0.0)
    traj = policy_trajectory(zero, SEEDS, residual="pid", pid_gains=gains, randomize=True,
                             pid_options=OPTIONS)  # fmt: skip
    expected = simulate("test2", "step", [gains] * 3, "actual", seeds=SEEDS, randomize=True,
                        pid_options=OPTIONS)  # fmt: skip
    assert_same(traj, expected)


def test_constant_servo_command_is_simulate_of_that_command():
    traj = policy_trajectory(lambda obs: np.full((len(obs), 1), -0.5), [7], reference="slope20",
                             disturbance="worn")  # fmt: skip
    expected = simulate("test2", np.full(len(traj.t), 45.0), None, "worn", seeds=7, y0_deg=92.0)
    np.testing.assert_array_equal(traj.y, expected.y)
    np.testing.assert_array_equal(traj.u, expected.u)


def test_bad_inputs():
    with pytest.raises(ValueError, match="fixed reference"):
        policy_trajectory(zero, [0], reference="random")
    with pytest.raises(ValueError, match="not finite"):
        policy_trajectory(lambda obs: np.full((len(obs), 1), np.nan), [0])


_WARM_THEN_ROLL = """
import numpy as np
from gripper_env.envs import kernels
from gripper_env.envs.rollout import policy_trajectory
from tuners.compile import _env

for env_id in ("gripper_env/GripperServo-v0", "gripper_env/GripperGainSchedule-v0"):
    _env(env_id)
    _env(env_id, parallel=True)
dispatchers = (kernels.step_serial, kernels.step_parallel)
warmed = [set(d.signatures) for d in dispatchers]
pid = {"residual": "pid", "pid_gains": (1.0, 9.0, -0.001), "residual_deg": 10.0}
for kwargs in ({}, pid):
    for seeds in ([0], list(range(64))):  # the serial kernel, and the parallel one
        traj = policy_trajectory(lambda obs: np.zeros((len(obs), 1)), seeds, **kwargs)
        assert np.isfinite(traj.y).all()
new = [sorted(map(str, set(d.signatures) - w)) for d, w in zip(dispatchers, warmed)]
print(new)
"""


def test_rollouts_step_with_the_kernels_the_warm_up_compiles():
    """A whole-episode rollout (``policy_trajectory``: the probe, ``rl play``, the grasp runs)
    calls the step kernel with the argument types the environments' own steps use, so
    ``python -m tuners.compile`` has compiled it: a rollout that recorded into arrays the
    environments leave out (``None``) was a specialisation of its own, 90-110 s of compiling
    on 2 cores the first time it ran (numba compiles one per argument type). In a fresh
    interpreter, so that no earlier test has loaded a signature."""
    out = subprocess.run([sys.executable, "-c", _WARM_THEN_ROLL], capture_output=True,
                         text=True, timeout=900, check=False)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "[[], []]", out.stdout

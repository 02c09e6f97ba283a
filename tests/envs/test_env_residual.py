"""GripperServo-v0's residual modes: the action is a bounded correction added to the reference
(fed straight to the servo) or to a fixed PID's output; checked against the simulation core."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import SERVO

import gripper_env  # noqa: F401
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from gripper_env.sim import BatchSimulator, simulate
from gripper_env.sim.layout import S_XI

GAINS = (1.0, 9.0, -0.001)  # the paper's tuned gains on TF test2
JC, JH = 56.5, 35.5  # centre and half-width of the jaw range (deg)


def positions(env, action, n_steps=None):
    """Measured angle (deg) at the end of each period under a constant action."""
    out = []
    while n_steps is None or len(out) < n_steps:
        obs, _, terminated, truncated, _ = env.step(np.array([action], np.float32))
        out.append(obs[0] * JH + JC)
        if terminated or truncated:
            break
    return np.array(out)


@pytest.mark.parametrize("action", [0.0, 0.4, -1.7])
def test_reference_residual_is_the_open_loop_run_of_reference_plus_correction(action):
    env = gym.make(SERVO, residual="reference", residual_deg=15.0)
    _, info = env.reset(seed=3)
    y = positions(env, action)
    assert len(y) == 1000
    ref = load_reference("step").values_deg
    command = ref + 15.0 * np.clip(action, -1.0, 1.0)  # the correction saturates at +/-1
    traj = simulate("test2", command, gains=None, disturbance="actual", seeds=info["noise_seed"],
                    y0_deg=92.0)  # fmt: skip
    np.testing.assert_allclose(y, traj.y[0, 19::20], rtol=0, atol=1e-4)


def test_zero_reference_residual_is_command_equals_reference():
    """The trivial policy "command = reference" is the zero action; its return is the reward's
    documented scale (minus the tracking IAE over 0.02 s x 35.5 deg, plus small terms)."""
    env = gym.make(SERVO, residual="reference")
    _, info = env.reset(seed=0)
    total = 0.0
    while True:
        _, reward, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        total += reward
        if terminated or truncated:
            break
    traj = simulate("test2", "step", gains=None, disturbance="actual", seeds=info["noise_seed"])
    iae = np.sum(np.abs(traj.r[0] - traj.y[0])) * 1e-3
    assert -total == pytest.approx(iae / (0.02 * JH), rel=0.05)


def test_pid_residual_zero_is_the_closed_loop_run():
    env = gym.make(SERVO, residual="pid", pid_gains=GAINS)
    obs, info = env.reset(seed=4)
    assert obs.shape == (7,)  # tracking, the PID's output, the previous action
    y = positions(env, 0.0)
    traj = simulate("test2", "step", gains=[GAINS], disturbance="actual", seeds=info["noise_seed"])
    np.testing.assert_allclose(y, traj.y[0, 19::20], rtol=0, atol=1e-4)


def test_pid_residual_adds_to_the_pid_output():
    """A constant correction c is a PID whose output is offset by c throughout: the core's run
    with the integrator state (which enters the output one to one) raised by c at the start."""
    bound, action = 12.0, -0.5
    env = gym.make(SERVO, residual="pid", pid_gains=GAINS, residual_deg=bound, disturbance="ideal")
    env.reset(seed=0)
    y = positions(env, action, n_steps=300)
    sim = BatchSimulator(load_plant("test2"))
    sim.configure(np.array([[*GAINS, 100.0]]), load_disturbance("ideal"))
    sim.reset(92.0, 0)
    sim.state[0, S_XI] += bound * action
    _, _, y_sim, _ = sim.advance(6000, load_reference("step").values_deg)
    np.testing.assert_allclose(y, y_sim[0, 19::20], rtol=0, atol=1e-4)
    # the observed controller output is the PID's, correction included
    obs, *_ = env.step(np.array([action], np.float32))
    _, u_next, _, _ = sim.advance(20, load_reference("step").values_deg, offset=6000)
    lo, hi = env.unwrapped.settings.command_range_deg
    assert obs[5] == pytest.approx((u_next[0, -1] - (lo + hi) / 2) / ((hi - lo) / 2), abs=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"residual": "command"}, "residual"),
        ({"residual": "reference", "residual_deg": 0.0}, "residual_deg"),
        ({"residual": "pid"}, "pid_gains"),
        ({"residual": "pid", "pid_gains": (1.0, np.nan, 0.0)}, "pid_gains"),
        ({"residual": "reference", "pid_gains": GAINS}, "pid_gains"),
    ],
)
def test_bad_residual_arguments_name_themselves(kwargs, name):
    with pytest.raises(ValueError, match=f"'{name}'"):
        gym.make(SERVO, **kwargs)

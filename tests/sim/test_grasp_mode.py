"""The PID's grasp mode in the simulation core: the core's PID is the Python PID, bit for bit,
and on the gripper it holds an object with the squeeze's force instead of winding up."""

import dataclasses

import numpy as np
import pytest

from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PID, GraspOptions, PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from gripper_env.sim import BatchSimulator, simulate
from gripper_env.sim.layout import S_GRASP, S_GRASP_YF, S_XI

PLANT = load_plant("test2")
ON_OBJECT = load_disturbance("actual").with_overrides({"mechanics": {"object_contact_deg": 45.0}})
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
GAINS = PIDGains(1.0, 9.0, -0.001)


def test_the_state_columns_are_the_pid_state_vector():
    assert (S_XI, S_GRASP, S_GRASP_YF) == (0, 2, 5)


@pytest.mark.parametrize(
    ("gains", "sign"),
    [(GAINS, 1), (PIDGains(-0.5, -3.6, 0.000186), -1), (PIDGains(3.4, 67.5, -0.0087), 1)],
    ids=["paper-tuned", "paper-hw-tuned", "optuna"],
)
def test_the_cores_pid_is_the_python_pid_bit_for_bit(gains, sign):
    """Closed loop on the actual gripper closing on an object: the Python PID fed the core's
    reference and measurement gives the core's command exactly, grasp and release included."""
    options = dataclasses.replace(OPTIONS, sign=sign)
    ref = load_reference("step")
    sim = BatchSimulator(PLANT)
    sim.configure(gains.as_array()[None, :], ON_OBJECT, options)
    sim.reset(ref.values_deg[0], seeds=3)
    pid = PID(gains, dt_s=PLANT.dt_s, options=options)
    pid.state[:] = sim.state[0, : len(pid.state)]
    r, u, y, _ = sim.advance(len(ref), ref.values_deg)
    python = np.array([pid.step(rk, yk) for rk, yk in zip(r[0], y[0], strict=True)])
    np.testing.assert_array_equal(python, u[0])
    # it did grasp: held 1 deg past the object during the grip, and let go for the un-grip
    grip = slice(ref.segments[0].start + 2000, ref.segments[1].start)
    assert np.all(np.abs(u[0, grip] - 44.0) < 0.5)
    assert pid.grasping == 0


def test_with_the_mode_the_jaw_squeezes_and_reopens_at_once():
    """The object test of test_simulator.py with the mode on: instead of a command run away to
    the servo's range (clamped at 0 deg), the command held 1 deg past the contact."""
    runs = {
        name: simulate(
            PLANT,
            "step",
            gains=[GAINS.as_array()],
            disturbance=ON_OBJECT,
            seeds=0,
            pid_options=dataclasses.replace(OPTIONS, grasp=grasp),
        )
        for name, grasp in (("plain", None), ("grasp", GraspOptions()))
    }
    hold = slice(3000, 10_000)
    assert runs["plain"].u[0, hold].min() == 0.0  # wound up to the range's end
    assert np.all(np.abs(runs["grasp"].u[0, hold] - 44.0) < 0.5)
    # the mechanics block's push: the plain PID stalls the servo, the grasp squeezes at 20 %
    assert runs["plain"].stall_s[0] > 5.0
    assert runs["grasp"].stall_s[0] < 0.2
    assert runs["grasp"].force_proxy[0] == pytest.approx(0.2, abs=0.03)
    t_open = {k: np.argmax(v.y_true[0, 10_000:] > 80) for k, v in runs.items()}
    assert t_open["grasp"] <= t_open["plain"]


def test_nothing_changes_while_the_jaw_moves_freely():
    """The benchmark's profile on the actual gripper, no object: bit-identical with and without
    the mode (every committed gains file was checked the same way; docs in the report)."""
    seeds = list(range(100000, 100004))
    for profile in ("step", "slope60"):
        a, b = (
            simulate(
                PLANT,
                profile,
                gains=np.tile(GAINS.as_array(), (4, 1)),
                disturbance="actual",
                seeds=seeds,
                randomize=True,
                pid_options=dataclasses.replace(OPTIONS, grasp=grasp),
            )
            for grasp in (None, GraspOptions())
        )
        np.testing.assert_array_equal(a.u, b.u)
        np.testing.assert_array_equal(a.y_true, b.y_true)

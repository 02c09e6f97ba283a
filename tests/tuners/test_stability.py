import control
import numpy as np
import pytest

from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.plants import load_plant
from gripper_env.simulation import simulate
from tests.conftest import PAPER_GAINS
from tuners.stability import closed_loop_stability, pid_state_space


def test_paper_tf_gains_are_stable_on_test2():
    for key in ("untuned_tf", "tuned_tf"):
        report = closed_loop_stability("test2", PIDGains(*PAPER_GAINS[key]))
        assert report.stable and report.max_pole_magnitude < 1.0


@pytest.mark.parametrize("plant", ["test2", "test3", "test4"])
@pytest.mark.parametrize("key", ["untuned_hw", "tuned_hw"])
def test_hardware_gains_need_the_opposite_sign(plant, key):
    gains = PIDGains(*PAPER_GAINS[key])
    assert not closed_loop_stability(plant, gains, PIDOptions(sign=1)).stable
    assert closed_loop_stability(plant, gains, PIDOptions(sign=-1)).stable


def test_test1_with_integral_action_is_slowly_unstable():
    report = closed_loop_stability("test1", PIDGains(*PAPER_GAINS["tuned_tf"]))
    assert not report.stable
    assert 1.0 < report.max_pole_magnitude < 1.001  # grows over seconds, not per step
    assert report.slowest_time_constant_s < 0  # a growth time, negated


def test_margins_of_a_p_controller_by_hand():
    # P on test4 (fast real pole at ~96 rad/s, gain ~1): the loop gain P*G never reaches -180 deg
    report = closed_loop_stability("test4", PIDGains(2.0, 0.0, 0.0))
    assert report.stable
    assert report.phase_margin_deg > 90


def test_pid_state_space_matches_the_simulation_core():
    # the linear closed loop built here reproduces the compiled kernel's ideal run
    plant = load_plant("test3")
    gains = PIDGains(0.8, 12.0, 0.002, 100.0)
    traj = simulate(plant, "step", gains=[gains.as_array()], disturbance="ideal", initial="zero")
    g = control.c2d(control.ss(plant.tf), plant.dt_s, "zoh")
    closed = control.feedback(control.series(pid_state_space(gains, plant.dt_s), g), 1)
    response = control.forced_response(closed, T=traj.t, U=traj.r[0])
    np.testing.assert_allclose(traj.y_true[0], np.ravel(response.outputs), rtol=1e-7, atol=1e-7)


def test_report_is_json_friendly():
    d = closed_loop_stability("test2", PIDGains(1.0, 9.0, -0.001)).as_dict()
    assert set(d) >= {"stable", "max_pole_magnitude", "poles", "gain_margin", "phase_margin_deg"}
    assert all(len(p) == 2 for p in d["poles"])

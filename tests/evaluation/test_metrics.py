import math
import warnings

import control
import numpy as np
import pytest

from gripper_env.evaluation.metrics import compute_metrics, fit_percent, sample_sd, step_metrics
from gripper_env.sim import simulate

DT = 1e-3


def first_order(tau, t):
    return 1.0 - np.exp(-t / tau)


def test_first_order_step_worked_by_hand():
    tau = 0.1
    t = np.arange(0, 2, DT)
    y = 92.0 + (21.0 - 92.0) * first_order(tau, t)  # a grip: 92 -> 21
    m = step_metrics(t, y, 92.0, 21.0)
    # rise 10-90 %: tau ln 9 ; settling to 2 %: tau ln 50 ; no overshoot
    assert m["rise_time_s"][0] == pytest.approx(tau * math.log(9), abs=2 * DT)
    assert m["settling_time_s"][0] == pytest.approx(tau * math.log(50), abs=2 * DT)
    assert m["overshoot_pct"][0] == 0.0 and m["undershoot_pct"][0] == 0.0
    assert m["steady_state_error_deg"][0] < 1e-3


def test_agrees_with_python_control_step_info():
    sys = control.tf([4.0], [1.0, 1.2, 4.0])  # underdamped: 15 % overshoot-ish
    t = np.arange(0, 10, DT)
    _, y = control.step_response(sys, T=t)
    ref = control.step_info(y, t, yfinal=1.0)
    for y_init, span in [(0.0, 1.0), (92.0, -71.0), (21.0, 71.0)]:
        m = step_metrics(t, y_init + span * y, y_init, y_init + span)
        assert m["overshoot_pct"][0] == pytest.approx(ref["Overshoot"], rel=1e-9)
        assert m["rise_time_s"][0] == pytest.approx(ref["RiseTime"], abs=1e-12)
        assert m["settling_time_s"][0] == pytest.approx(ref["SettlingTime"], abs=1e-12)
        assert m["peak_time_s"][0] == pytest.approx(ref["PeakTime"], abs=1e-12)


def test_never_reached_is_inf_not_nan():
    t = np.arange(0, 1, DT)
    m = step_metrics(t, np.full((2, len(t)), 92.0), 92.0, 21.0)
    assert np.all(np.isinf(m["rise_time_s"])) and np.all(np.isinf(m["settling_time_s"]))
    with pytest.raises(ValueError, match="y_final != y_init"):
        step_metrics(t, np.zeros(len(t)), 1.0, 1.0)


def test_sd_is_matlab_std():
    x = np.array([2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0])
    assert sample_sd(x) == pytest.approx(math.sqrt(32 / 7))  # ddof = 1


def test_fit_percent_by_hand():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full(4, 2.5)) == pytest.approx(0.0)
    # ||e|| = 1, ||y - mean|| = sqrt(5)
    assert fit_percent(y, y + np.array([1.0, 0, 0, 0])) == pytest.approx(
        100 * (1 - 1 / math.sqrt(5))
    )
    assert fit_percent(y, -y) < 0


def test_run_metrics_of_a_known_trajectory():
    traj = simulate("test2", "step", gains=[(1.0, 9.0, -0.001)], disturbance="ideal")
    m = compute_metrics(traj).as_dict(0)
    e = traj.r[0] - traj.y[0]
    assert m["iae"] == pytest.approx(np.abs(e).sum() * DT)
    assert m["ise"] == pytest.approx((e**2).sum() * DT)
    assert m["itae"] == pytest.approx((traj.t * np.abs(e)).sum() * DT)
    assert m["control_effort"] == pytest.approx(np.abs(np.diff(traj.u[0])).sum())
    assert m["sd_deg"] == pytest.approx(np.std(traj.y[0], ddof=1))
    assert m["sd_gap_deg"] == pytest.approx(abs(np.std(traj.r[0], ddof=1) - m["sd_deg"]))
    assert set(m["grip"]) >= {
        "overshoot_pct",
        "rise_time_s",
        "settling_time_s",
        "steady_state_error_deg",
    }
    assert m["stable"] is True


def test_paper_qualitative_result_on_test2():
    """Table 3 on TF test2: the untuned gains overshoot (~40 %), the tuned ones do not."""
    traj = simulate("test2", "step", gains=[(-0.4, 7, -0.045), (1, 9, -0.001)], disturbance="ideal")
    m = compute_metrics(traj)
    assert 30 < m.grip["overshoot_pct"][0] < 50 and 30 < m.ungrip["overshoot_pct"][0] < 50
    assert m.grip["overshoot_pct"][1] < 0.1 and m.ungrip["overshoot_pct"][1] < 0.1
    # and the SD ordering of Table 4: untuned above tuned
    assert m.run["sd_deg"][0] > m.run["sd_deg"][1]


def test_unstable_runs_get_inf_and_no_warnings():
    traj = simulate(
        "test2", "step", gains=[(-0.3, -5, -0.0005), (1, 9, -0.001)], disturbance="ideal"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = compute_metrics(traj)
    d = m.as_dict(0)
    assert d["stable"] is False and math.isinf(d["iae"]) and math.isinf(d["grip"]["overshoot_pct"])
    values = [v for v in d.values() if isinstance(v, float)]
    assert not any(math.isnan(v) for v in values)
    assert m.as_dict(1)["stable"] is True


def test_a_loop_that_swings_between_the_stops_is_classified_as_diverged():
    """A loop unstable with the hold but bounded by the command range and the stops never
    leaves the divergence bound; its sustained swing classifies it (issue 20)."""
    from gripper_env.evaluation.metrics import OSCILLATION_LIMIT_DEG
    from gripper_env.model.pid import PIDOptions
    from gripper_env.sim import simulate

    options = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
    seeds = np.arange(100000, 100004)
    unstable = simulate("test4", "step", np.repeat([[3.43, 67.5, -0.0087, 100.0]], 4, 0),
                        "actual", seeds=seeds, randomize=True, pid_options=options)  # fmt: skip
    assert unstable.stable.all()  # the core sees bounded states
    m = compute_metrics(unstable, "true")
    assert np.all(m.run["oscillation_deg"] > OSCILLATION_LIMIT_DEG) and not m.stable.any()
    assert np.all(np.isinf(m.run["iae"]))
    settled = simulate("test4", "step", np.repeat([[0.33, 28.5, 0.0, 100.0]], 4, 0), "actual",
                       seeds=seeds, randomize=True, pid_options=options)  # fmt: skip
    ms = compute_metrics(settled, "true")
    assert ms.stable.all() and np.all(ms.run["oscillation_deg"] < 4.0)  # friction hunting only


def test_step_overshoot_is_the_first_peak_of_an_underdamped_loop():
    """The first-rise overshoot of a second-order step is exp(-pi zeta / sqrt(1 - zeta^2))
    (python-control's step_info agrees); a creep past the target seconds later is hunting, not
    step overshoot, and the whole-hold overshoot does count it."""
    from gripper_env.evaluation.metrics import first_rise_overshoot

    zeta, wn = 0.5, 6.0
    sys = control.tf([wn**2], [1.0, 2 * zeta * wn, wn**2])
    t = np.arange(0, 8, DT)
    _, y = control.step_response(sys, T=t)
    analytic = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    late = np.where(t > 5.0, 0.3 * np.minimum(t - 5.0, 1.0), 0.0)  # a slow creep 30 % past
    for y_init, span in [(0.0, 1.0), (92.0, -71.0)]:
        yy = y_init + span * (y + late)
        first = first_rise_overshoot(yy[None, :], y_init, y_init + span, DT)[0]
        assert first == pytest.approx(analytic, rel=2e-3)
        assert first == pytest.approx(control.step_info(y, t)["Overshoot"], rel=2e-3)
        whole = step_metrics(t, yy, y_init, y_init + span)["overshoot_pct"][0]
        assert whole == pytest.approx(30.0, abs=0.5)  # the creep's, not the step's


def test_jaw_envelope_and_step_overshoot_in_the_metrics():
    """compute_metrics reports the true jaw's lowest and highest angle and the step overshoot
    of both moves (the jaw's own extremes, checked against the trajectory)."""
    traj = simulate("test2", "step", gains=[(1.0, 9.0, -0.001)] * 3, disturbance="actual",
                    seeds=[0, 1, 2])  # fmt: skip
    m = compute_metrics(traj, "true")
    assert np.allclose(m.run["jaw_min_deg"], traj.y_true.min(axis=1))
    assert np.allclose(m.run["jaw_max_deg"], traj.y_true.max(axis=1))
    assert np.all(m.grip["step_overshoot_pct"] <= m.grip["overshoot_pct"] + 1e-12)
    assert np.all(m.grip["step_overshoot_pct"] >= 0.0)

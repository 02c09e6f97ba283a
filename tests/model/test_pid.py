import control
import numpy as np
import pytest

from gripper_env.model.pid import PID, PIDGains, PIDOptions


def run(pid, r, y):
    return np.array([pid.step(ri, yi) for ri, yi in zip(r, y, strict=True)])


def test_first_samples_worked_by_hand():
    # P=1, I=9, D=-0.001, N=100, dt=1e-3, at rest at 92 then a grip step to 21 (e = -71)
    pid = PID(PIDGains(1.0, 9.0, -0.001), dt_s=1e-3)
    pid.reset(u0=92.0, y0=92.0)
    # k=0: d = D*N*(e - 0) = -0.1 * -71 = 7.1 ; u = -71 + 92 + 7.1
    assert pid.step(21.0, 92.0) == pytest.approx(28.1)
    # xi = 92 + 1e-3*9*(-71) = 91.361 ; xf = 0.1*(-71) = -7.1 ; d = -0.1*(-71 + 7.1) = 6.39
    assert pid.step(21.0, 92.0) == pytest.approx(-71 + 91.361 + 6.39)


def test_matches_simulinks_discrete_transfer_function():
    """Unsaturated PID == P + I*Ts/(z-1) + D*N/(1 + N*Ts/(z-1)) (Forward Euler)."""
    p, i, d, n, ts = -0.4, 7.0, -0.045, 100.0, 1e-3
    z = control.tf([1, 0], [1], ts)
    c = p + i * ts / (z - 1) + d * n / (1 + n * ts / (z - 1))
    e = np.random.default_rng(1).normal(size=500).cumsum()
    _, u_ref = control.forced_response(c, T=np.arange(500) * ts, U=e)
    # without the grasp mode: a jaw that never moves (y = 0) under a growing command reads as
    # blocked (tests/model/test_pid_grasp.py)
    pid = PID(PIDGains(p, i, d, n), dt_s=ts, options=PIDOptions(anti_windup="none", grasp=None))
    pid.reset()
    u = run(pid, e, np.zeros_like(e))
    np.testing.assert_allclose(u, u_ref, rtol=1e-10, atol=1e-10)


def test_sign_convention_flips_the_error():
    a = PID(PIDGains(-0.5, -3.6, 0.000186), options=PIDOptions(sign=-1))
    b = PID(PIDGains(0.5, 3.6, -0.000186))
    a.reset()
    b.reset()
    r, y = np.linspace(0, 5, 50), np.sin(np.arange(50))
    np.testing.assert_allclose(run(a, r, y), run(b, r, y), rtol=1e-12)


def test_output_limits_and_clamping_anti_windup():
    opts = PIDOptions(output_limits=(0.0, 10.0), anti_windup="clamping", grasp=None)
    pid = PID(PIDGains(1.0, 100.0, 0.0), options=opts)
    pid.reset()
    u = run(pid, np.full(1000, 50.0), np.zeros(1000))
    assert u.max() == 10.0 and u.min() >= 0.0
    # the integrator stopped once the output saturated: it holds at most what reached the limit
    assert pid.state[0] <= 10.0 + 1e-9
    # without anti-windup it keeps integrating
    free = PID(
        PIDGains(1.0, 100.0, 0.0),
        options=PIDOptions((0.0, 10.0), anti_windup="none", grasp=None),
    )
    free.reset()
    run(free, np.full(1000, 50.0), np.zeros(1000))
    assert free.state[0] == pytest.approx(100.0 * 50.0 * 1.0, rel=1e-9)


def test_back_calculation_bleeds_the_integrator():
    opts = PIDOptions(
        output_limits=(0.0, 10.0), anti_windup="back-calculation", kb=50.0, grasp=None
    )
    pid = PID(PIDGains(1.0, 100.0, 0.0), options=opts)
    pid.reset()
    run(pid, np.full(2000, 50.0), np.zeros(2000))
    # steady state of xi' = I e + kb (u - v): I*50 + kb*(10 - (50 + xi)) = 0
    assert pid.state[0] == pytest.approx((100 * 50 + 50 * (10 - 50)) / 50, rel=1e-3)


def test_changing_integral_gain_is_bumpless():
    pid = PID(PIDGains(0.0, 5.0, 0.0))
    pid.reset()
    run(pid, np.ones(100), np.zeros(100))
    before = pid.state.copy()
    pid.gains = PIDGains(0.0, 50.0, 0.0)
    # with I changed, the next output is the integral accumulated so far: no jump
    assert pid.step(1.0, 0.0) == pytest.approx(before[0])


def test_derivative_on_measurement_has_no_kick():
    on_err = PID(PIDGains(0.0, 0.0, 1.0))
    on_meas = PID(PIDGains(0.0, 0.0, 1.0), options=PIDOptions(derivative_on="measurement"))
    on_err.reset()
    on_meas.reset(y0=0.0)
    assert on_err.step(10.0, 0.0) == pytest.approx(1.0 * 100 * 10.0)
    assert on_meas.step(10.0, 0.0) == 0.0


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1"])
def test_non_finite_gains_are_refused(bad):
    with pytest.raises(ValueError, match="PID gain P must be a finite number"):
        PIDGains(bad, 1.0, 0.0)


def test_unstable_filter_is_refused():
    with pytest.raises(ValueError, match="N\\*dt=2"):
        PID(PIDGains(1, 1, 1, N=2000.0), dt_s=1e-3)


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="anti_windup"):
        PIDOptions(anti_windup="bogus")
    with pytest.raises(ValueError, match="output_limits"):
        PIDOptions(output_limits=(5.0, 1.0))
    with pytest.raises(ValueError, match="sign"):
        PIDOptions(sign=2)


def test_gains_beyond_a_million_are_refused_by_name():
    """1e308 is finite, but it overflows the simulation and the margins: refused, named."""
    from gripper_env.model.pid import MAX_GAIN

    PIDGains(MAX_GAIN, -MAX_GAIN, MAX_GAIN)
    for i, name in enumerate("PID"):
        values = [1.0, 1.0, 0.0]
        values[i] = 1e308
        with pytest.raises(ValueError, match=f"PID gain {name} = 1e\\+308 is out of range"):
            PIDGains(*values)

import warnings

import control
import numpy as np
import pytest

from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import Plant, load_plant
from gripper_env.model.references import load_reference
from gripper_env.paper import PID_GAINS as PAPER_GAINS
from gripper_env.sim import BatchSimulator, simulate
from gripper_env.sim.layout import S_CMD

TS = 1e-3
#: Simulink's PID block, the linear loop python-control solves: no grasp mode (on test1 a free
#: jaw moves too slowly to tell from a blocked one, gripper_env.model.pid)
SIMULINK = PIDOptions(grasp=None)


def discrete_pid(p, i, d, n=100.0, ts=TS):
    """Simulink's Forward Euler PID as a python-control state-space system."""
    z = control.tf([1, 0], [1], ts)
    return control.ss(p + i * ts / (z - 1) + d * n / (1 + n * ts / (z - 1)))


def discrete_plant(plant):
    """Exact ZOH of the plant, built in state space (a TF with poles at z ~ 1 loses digits)."""
    return control.c2d(control.ss(plant.tf), plant.dt_s, method="zoh")


@pytest.mark.parametrize(
    "gains", [PAPER_GAINS["untuned_tf"], PAPER_GAINS["tuned_tf"], (0.5, 2.0, 0.0)]
)
def test_ideal_closed_loop_matches_python_control(paper_plant_name, gains):
    """The acceptance test of the core: 1e-9 relative to forced_response of the same loop."""
    plant = load_plant(paper_plant_name)
    loop = control.feedback(discrete_plant(plant) * discrete_pid(*gains), 1)
    ref = load_reference("step")
    with np.errstate(all="ignore"):  # the reference solution overflows where the loop diverges
        _, y_ref = control.forced_response(loop, T=ref.t_s, U=ref.values_deg)
    traj = simulate(plant, ref, gains=[gains], disturbance="ideal", initial="zero",
                    pid_options=SIMULINK)  # fmt: skip
    if not np.all(np.abs(y_ref) < 1e9):
        # e.g. the paper's untuned gains on test4: the loop diverges, and is flagged so
        assert not traj.stable[0]
        assert np.max(np.abs(loop.poles())) > 1.0
        return
    # (test1 with integral action is slowly unstable, |z| = 1.0001, yet finite over 20 s)
    assert traj.stable[0]
    scale = np.max(np.abs(y_ref))
    np.testing.assert_allclose(traj.y_true[0], y_ref, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(traj.y[0], traj.y_true[0], rtol=0, atol=1e-9 * scale)


def test_ideal_from_rest_is_superposition(paper_plant_name):
    """Starting at the exact equilibrium at 92 deg, y - 92 is the zero-state response to r - 92."""
    plant = load_plant(paper_plant_name)
    gains = PAPER_GAINS["tuned_tf"]
    loop = control.feedback(discrete_plant(plant) * discrete_pid(*gains), 1)
    ref = load_reference("step")
    _, y_ref = control.forced_response(loop, T=ref.t_s, U=ref.values_deg - 92.0)
    traj = simulate(plant, ref, gains=[gains], disturbance="ideal", initial="equilibrium",
                    pid_options=SIMULINK)  # fmt: skip
    np.testing.assert_allclose(traj.y_true[0] - 92.0, y_ref, rtol=0, atol=1e-9 * 92)


def test_ideal_open_loop_matches_python_control(paper_plant_name):
    plant = load_plant(paper_plant_name)
    ref = load_reference("slope20")
    _, y_ref = control.forced_response(discrete_plant(plant), T=ref.t_s, U=ref.values_deg)
    traj = simulate(plant, ref, gains=None, disturbance="ideal", initial="zero")
    np.testing.assert_allclose(traj.y_true[0], y_ref, rtol=0, atol=1e-9 * 92)
    np.testing.assert_array_equal(traj.u[0], ref.values_deg)


def test_batch_equals_single_runs():
    gains = np.array([PAPER_GAINS["tuned_tf"], PAPER_GAINS["untuned_tf"], (0.3, 4.0, 0.0)] * 7)
    seeds = np.arange(len(gains))
    batch = simulate("test2", "step", gains=gains, disturbance="actual", seeds=seeds)
    for i in (0, 1, 2, 20):
        one = simulate("test2", "step", gains=[gains[i]], disturbance="actual", seeds=seeds[i])
        np.testing.assert_array_equal(batch.y[i], one.y[0])
        np.testing.assert_array_equal(batch.u[i], one.u[0])


def test_same_seed_same_run_other_seed_other_noise():
    a = simulate("test2", "step", gains=[PAPER_GAINS["tuned_tf"]], seeds=5)
    b = simulate("test2", "step", gains=[PAPER_GAINS["tuned_tf"]], seeds=5)
    c = simulate("test2", "step", gains=[PAPER_GAINS["tuned_tf"]], seeds=6)
    np.testing.assert_array_equal(a.y, b.y)
    assert not np.array_equal(a.y, c.y)


def test_randomised_parameters_follow_the_seed():
    a = simulate("test2", "slope20", disturbance="worn", seeds=[1, 2], randomize=True)
    b = simulate("test2", "slope20", disturbance="worn", seeds=[1, 2], randomize=True)
    np.testing.assert_array_equal(a.y_true, b.y_true)
    assert not np.array_equal(a.y_true[0], a.y_true[1])


def test_unstable_gains_are_flagged_without_warnings():
    gains = [PAPER_GAINS["untuned_hw"], PAPER_GAINS["tuned_hw"], PAPER_GAINS["tuned_tf"]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        traj = simulate("test2", "step", gains=gains, disturbance="ideal")
    assert traj.stable.tolist() == [False, False, True]
    assert np.isnan(traj.y[0, -1]) and np.all(np.isfinite(traj.y[2]))
    # the paper's hardware gains are stable with the opposite error sign (e = y - r)
    flipped = simulate(
        "test2", "step", gains=gains[:2], disturbance="ideal", pid_options=PIDOptions(sign=-1)
    )
    assert flipped.stable.all()


def test_actual_chain_quantises_holds_and_limits():
    d = load_disturbance("actual")
    traj = simulate("test2", "step", gains=[PAPER_GAINS["untuned_tf"]], disturbance=d, seeds=3)
    yt = traj.y_true[0]
    closed, opened = d.mechanics.limits_deg
    assert yt.min() >= closed and yt.max() <= opened  # mechanical stops
    # the paper's untuned gains overshoot on the actual gripper too (its Figure 11a): the stops
    # lie beyond 21 and 92 deg, so the overshoot shows before the jaw meets one
    assert yt.min() < 21.0 - 5.0 and yt.max() > 92.0 + 5.0
    lsb = d.sensor.lsb_deg
    codes = traj.y[0] / lsb
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-6)  # 10-bit ADC grid
    # the ideal loop overshoots 40 %, far past the stops; the real jaw cannot
    ideal = simulate("test2", "step", gains=[PAPER_GAINS["untuned_tf"]], disturbance="ideal")
    assert ideal.y_true[0].min() < closed - 10


def test_servo_sees_whole_degrees_every_20_ms():
    # open loop with a smooth reference: the plant input is piecewise constant over 20 samples
    plant = load_plant("test4")
    sim = BatchSimulator(plant)
    d = load_disturbance({"extends": "actual", "friction": {"model": "none"}})
    sim.configure(None, d)
    sim.reset(50.0, seeds=0)
    r = 50.0 + 10.0 * np.sin(np.arange(2000) * 2e-3)
    held = []
    for k in range(0, 2000):
        sim.advance(1, r, offset=k)
        held.append(sim.state[0, S_CMD])
    held = np.array(held)
    changes = np.flatnonzero(np.diff(held)) + 1
    assert len(changes) > 5
    assert np.all(changes % 20 == 0)
    np.testing.assert_array_equal(held, np.round(held))


def test_stick_slip_on_the_slow_slope():
    """With the actual preset the 60 s slope moves in jumps; with ideal it glides."""
    actual = simulate("test2", "slope60", disturbance="actual", seeds=0)
    ideal = simulate("test2", "slope60", disturbance="ideal")
    window = slice(10_000, 50_000)  # during the grip ramp
    v_act = np.abs(np.diff(actual.y_true[0, window])) / TS
    v_ideal = np.abs(np.diff(ideal.y_true[0, window])) / TS
    # ideal: a steady 71/60 deg/s; actual: mostly stuck, with short fast slips
    assert np.median(v_ideal) == pytest.approx(71 / 60, rel=0.01)
    assert np.mean(v_act < 0.05) > 0.5
    assert v_act.max() > 5 * 71 / 60
    # it still gets there on average
    assert abs(actual.y_true[0, 50_000] - ideal.y_true[0, 50_000]) < 3.0


def test_object_in_the_jaws_stops_closing_and_winds_up_without_anti_windup():
    """The plain PID (no grasp mode; with it: tests/sim/test_grasp_mode.py)."""
    d = load_disturbance("actual").with_overrides({"mechanics": {"object_contact_deg": 45.0}})
    clamp = simulate(
        "test2",
        "step",
        gains=[(0.2, 5.0, 0.0)],
        disturbance=d,
        pid_options=PIDOptions(output_limits=(0, 180), anti_windup="clamping", grasp=None),
    )
    free = simulate(
        "test2",
        "step",
        gains=[(0.2, 5.0, 0.0)],
        disturbance=d,
        pid_options=PIDOptions(anti_windup="none", grasp=None),
    )
    grip = slice(1000, 10_000)
    assert clamp.y_true[0, grip].min() == pytest.approx(45.0)
    # the command keeps pushing below the contact angle; without anti-windup it runs away
    assert free.u[0, 9_999] < -50 and clamp.u[0, 9_999] >= 0.0
    # ...and then it takes longer to reopen
    t_open_free = np.argmax(free.y_true[0, 10_000:] > 80)
    t_open_clamp = np.argmax(clamp.y_true[0, 10_000:] > 80)
    assert t_open_free > t_open_clamp


def test_sensor_delay_shifts_the_measurement():
    d = load_disturbance("ideal").with_overrides({"sensor": {"delay_s": 0.005}})
    traj = simulate("test4", "slope20", disturbance=d)
    np.testing.assert_allclose(traj.y[0, 5:], traj.y_true[0, :-5], atol=1e-9)


def test_gains_can_change_between_steps():
    plant = load_plant("test2")
    sim = BatchSimulator(plant)
    sim.configure([PAPER_GAINS["tuned_tf"]], load_disturbance("ideal"))
    sim.reset(92.0)
    ref = load_reference("step").values_deg
    sim.advance(5000, ref)
    u_before = sim.state[0, 0]
    sim.set_gains([(1.0, 30.0, -0.001)])
    _r, u, y, _yt = sim.advance(1, ref, offset=5000)
    # bumpless in I: the output continues from the same integrator value
    assert u[0, 0] == pytest.approx(u_before + 1.0 * (ref[5000] - y[0, 0]) + 0.0, abs=0.5)


def test_bad_inputs():
    with pytest.raises(ValueError, match="gains must be finite"):
        simulate("test2", "step", gains=[(np.nan, 1.0, 0.0)])
    with pytest.raises(ValueError, match=r"shape \(B, 3\)"):
        simulate("test2", "step", gains=[(1.0, 2.0)])
    with pytest.raises(ValueError, match="batch sizes disagree"):
        simulate("test2", "step", gains=np.ones((3, 3)), seeds=[1, 2])
    with pytest.raises(ValueError, match="N\\*dt < 2"):
        simulate("test2", "step", gains=[(1.0, 1.0, 0.0, 5000.0)])
    with pytest.raises(ValueError, match="initial must be"):
        simulate("test2", "step", gains=[(1.0, 1.0, 0.0)], initial="warm")


def test_noise_generator_is_standard_normal():
    from scipy import stats

    from gripper_env.sim.noise import normal_draws

    x = normal_draws(11, 200_000)
    assert abs(x.mean()) < 0.01 and abs(x.std() - 1) < 0.01
    assert stats.kstest(x, "norm").pvalue > 1e-3
    # the ziggurat's tail beyond r = 3.4426 has the normal's mass
    assert np.mean(np.abs(x) > 3.442619855899) == pytest.approx(2 * stats.norm.sf(3.4426), rel=0.2)
    np.testing.assert_array_equal(x[:10], normal_draws(11, 10))
    assert not np.array_equal(x[:10], normal_draws(12, 10))


def test_measurement_noise_has_the_configured_spread():
    d = load_disturbance("ideal").with_overrides({"sensor": {"noise_std_deg": 0.4}})
    traj = simulate("test4", "step", gains=None, disturbance=d, seeds=3)
    resid = traj.y[0] - traj.y_true[0]
    assert np.std(resid) == pytest.approx(0.4, rel=0.03)


def test_rate_limit_bounds_the_servo_command():
    d = load_disturbance("ideal").with_overrides(
        {"command": {"rate_limit_deg_s": 100.0, "refresh_period_s": 0.02}}
    )
    traj = simulate("test4", "step", gains=None, disturbance=d)
    # 71 deg at 100 deg/s: the plant input needs 0.71 s, so the output cannot arrive sooner
    assert traj.y_true[0, 1000 + 600] > 21.0 + 5.0
    assert traj.y_true[0, 1000 + 1500] == pytest.approx(21.0, abs=1.0)
    # averaged over 0.1 s the jaw cannot move faster than the command (2 deg per 20 ms frame)
    slope = np.diff(traj.y_true[0, 1000:1800:100]) / 0.1
    assert np.min(slope) > -100.0 * 1.1


def test_backlash_loses_motion_on_reversal():
    play = 2.0
    d = load_disturbance("ideal").with_overrides({"friction": {"backlash_deg": play}})
    r = np.concatenate([np.full(500, 50.0), np.linspace(50, 60, 2000), np.linspace(60, 50, 2000)])
    traj = simulate("test4", r, gains=None, disturbance=d)
    ideal = simulate("test4", r, gains=None, disturbance="ideal")
    # going up the output lags the input by half the play; right after the turn it stays put
    assert traj.y_true[0, 2400] == pytest.approx(ideal.y_true[0, 2400] - play / 2, abs=0.05)
    turn = 2500
    assert np.ptp(traj.y_true[0, turn + 50 : turn + 350]) < 0.1


@pytest.mark.parametrize("closed", [False, True])
def test_third_order_plant_matches_python_control(closed):
    """Plants above order 2 take the core's general state update (kept out of the hot loop)."""
    # (s + 2) / ((s + 1)(s + 3)(0.1 s + 1)): three real poles, one zero, unit DC gain x 2/3
    plant = Plant("order3", num=[1.0, 2.0], den=list(np.polymul(np.polymul([1, 1], [1, 3]),
                                                                [0.1, 1.0])))  # fmt: skip
    ref = load_reference("step")
    p, i, d = 0.8, 2.0, 0.0
    if closed:
        loop = control.feedback(discrete_plant(plant) * discrete_pid(p, i, d), 1)
        _, y_ref = control.forced_response(loop, T=ref.t_s, U=ref.values_deg)
        # (DC gain 2/3: the command rests 50 % past the jaw, no position servo: no grasp mode)
        traj = simulate(plant, ref, gains=[[p, i, d]], disturbance="ideal", initial="zero",
                        pid_options=SIMULINK)  # fmt: skip
    else:
        _, y_ref = control.forced_response(discrete_plant(plant), T=ref.t_s, U=ref.values_deg)
        traj = simulate(plant, ref, gains=None, disturbance="ideal", initial="zero")
    assert plant.order == 3
    np.testing.assert_allclose(traj.y_true[0], y_ref, rtol=0, atol=1e-9 * 92)
    # the same run in 20-step pieces (as the environments step it): the state carries over
    sim = BatchSimulator(plant)
    sim.configure([[p, i, d]] if closed else None, load_disturbance("ideal"), SIMULINK)
    sim.reset(ref.values_deg[0], initial="zero")
    pieces = [sim.advance(20, ref.values_deg, offset=k)[3][0] for k in range(0, len(ref), 20)]
    np.testing.assert_array_equal(np.concatenate(pieces), traj.y_true[0])


@pytest.mark.parametrize("command, stalled", [(10.0, True), (17.0, False)])
def test_contact_stall_and_force_hand_worked(command, stalled):
    """Open loop, the servo commanded 10 or 3 deg beyond a stop at 20 deg (stall band 5 deg):
    contact is every step the jaw sits on the stop, stall all of it only for the deep push, and
    the force proxy is the push over the band, capped at 1."""
    d = load_disturbance("ideal").with_overrides(
        {"mechanics": {"limits_deg": [20.0, 100.0], "stall_band_deg": 5.0}}
    )
    ref = np.concatenate([np.full(100, 50.0), np.full(1900, command)])
    traj = simulate("test4", ref, disturbance=d)
    on_stop = traj.y_true[0] == 20.0
    # contact counts from the step the jaw lands (its recorded angle is still above the stop)
    assert traj.contact_s[0] == pytest.approx(on_stop.sum() * TS, abs=1.5 * TS)
    assert traj.contact_s[0] > 1.7
    assert traj.stall_s[0] == pytest.approx(traj.contact_s[0] if stalled else 0.0)
    assert traj.force_proxy[0] == pytest.approx(min((20.0 - command) / 5.0, 1.0))
    free = simulate("test4", ref, disturbance="ideal")
    assert free.contact_s[0] == 0.0 and free.stall_s[0] == 0.0 and free.force_proxy[0] == 0.0


def test_servo_effort_is_the_variation_of_the_held_command():
    """Open loop with whole-degree commands at 50 Hz: a 0.3 deg dither below the quantum is
    invisible to the servo, a ramp of 10 deg costs exactly 10 deg, and a step back 10 more."""
    d = load_disturbance({"extends": "actual", "friction": {"model": "none"}})
    t = np.arange(3000) * TS
    ref = 50.0 + np.clip((t - 0.5) * 10.0, 0.0, 10.0) + 0.3 * np.sin(2 * np.pi * 7 * t)
    ref[2500:] = 50.0
    traj = simulate("test4", ref, disturbance=d)
    assert traj.servo_effort_deg[0] == pytest.approx(20.0)
    assert np.sum(np.abs(np.diff(traj.u[0]))) > 30.0  # what the old effort measure counted

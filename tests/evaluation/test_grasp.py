"""The grasp-and-hold scenario (gripper_env.evaluation.grasp) against hand-worked cases."""

import dataclasses
import math

import numpy as np
import pytest

from gripper_env.evaluation.grasp import (
    CONTINUOUS_CURRENT_FRACTION,
    FULL_STALL_LIMIT_S,
    STALL_TORQUE_NM,
    THERMAL_TIME_CONSTANT_S,
    GraspResult,
    GraspScenario,
    arduino_grasp,
    grasp_admission,
    simulate_grasp,
    stall_force_n,
    summarize_grasp,
    thermal_overload_at,
    thermal_state,
)
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import GraspOptions, PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.sim import simulate

PLANT = load_plant("test2")
ACTUAL = load_disturbance("actual")
#: The jaw's stops (12 and 100 deg) and the servo's range, nothing else: no friction, no
#: quantisation, no 20 ms hold, a perfect sensor. Pushes are then exact.
FRICTIONLESS = load_disturbance(
    {"name": "frictionless", "command": {"range_deg": [0.0, 180.0]},
     "mechanics": {"limits_deg": [12.0, 100.0], "stall_band_deg": 5.0}}
)  # fmt: skip
#: The plain PID (no grasp mode), whose wind-up the scenario exposes; and with the mode.
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping", grasp=None)
GRASP = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping", grasp=GraspOptions())
PAPER_TUNED = PIDGains(1.0, 9.0, -0.001)
SEEDS = (100000, 100001)


def _trip_after(fraction: float) -> float:
    """Hand-worked: a constant push at ``fraction`` of stall from cold trips after
    ``-tau ln(1 - i_c^2 / fraction^2)``."""
    return -THERMAL_TIME_CONSTANT_S * math.log(1 - CONTINUOUS_CURRENT_FRACTION**2 / fraction**2)


def test_the_servo_constant_is_the_datasheet_rating_in_si_units():
    assert STALL_TORQUE_NM == pytest.approx(3.8 * 9.80665 / 100)  # 3.8 kg cm
    assert stall_force_n(GraspScenario()) == pytest.approx(STALL_TORQUE_NM / 0.05)
    assert _trip_after(1.0) == pytest.approx(FULL_STALL_LIMIT_S)


def test_without_an_object_there_is_no_force_and_no_grasp():
    scenario = GraspScenario(object_deg=None)  # the close command (38) lies above the stop (12)
    run = simulate_grasp(PLANT, ACTUAL, PAPER_TUNED, scenario, options=OPTIONS, seeds=SEEDS)
    r = run.result("g", "c")
    assert not run.touching.any() and not run.force_fraction.any()
    assert math.isnan(r.time_to_grasp_s)
    assert r.holding_force_n == 0.0 and r.min_force_n == 0.0 and r.holding_force_pct == 0.0
    assert not r.overload and r.overload_at_s is None
    assert not r.held  # 0 N < the required 1 N


@pytest.mark.parametrize(("p", "push_deg"), [(27.0, 2.0), (28.0, 4.0), (29.0, 6.0)])
def test_a_p_controller_holds_with_the_force_the_mechanics_formula_gives(p, push_deg):
    """P only, no friction: held at the object (40 deg) the PID outputs its rest bias (92, the
    open angle it started at) plus P (38 - 40), so the push is 40 - (92 - 2 P) deg and the
    force min(push / 5, 1) * stall torque / lever."""
    scenario = GraspScenario()
    run = simulate_grasp(PLANT, FRICTIONLESS, PIDGains(p, 0.0, 0.0), scenario, options=OPTIONS)
    hold = run.t_s >= scenario.hold_window_s[0]
    assert np.all(run.command_deg[0, hold] == 92.0 - 2.0 * p)
    fraction = min(push_deg / 5.0, 1.0)
    r = run.result("g", "c")
    expected = fraction * STALL_TORQUE_NM / scenario.finger_lever_m
    assert r.holding_force_n == pytest.approx(expected, rel=1e-12)
    assert r.min_force_n == pytest.approx(expected, rel=1e-12)
    assert r.holding_force_pct == pytest.approx(100 * fraction)
    # the overload: none at 40 %, else the hand-worked thermal trip after the first touch
    touch = run.t_s[np.argmax(run.touching[0])]
    if fraction <= 0.4:
        assert r.overload_at_s is None and r.held
    else:
        assert r.overload_at_s == pytest.approx(touch + _trip_after(fraction), abs=1.5e-3)
        assert not r.held


def test_the_overload_trips_exactly_at_the_stated_limit():
    t = np.arange(6000) * 1e-3
    stall = np.where(t >= 0.5, 1.0, 0.0)  # full stall current from 0.5 s
    assert thermal_overload_at(t, stall) == pytest.approx(0.5 + FULL_STALL_LIMIT_S, abs=1e-9)
    # one sample short of the limit: no trip
    assert thermal_overload_at(t[:2499], stall[:2499]) is None
    assert thermal_overload_at(t[:2500], stall[:2500]) == pytest.approx(2.5, abs=1e-9)
    # at the continuous rating, never; a little above it, as the hand formula says
    assert thermal_overload_at(t, np.full_like(t, CONTINUOUS_CURRENT_FRACTION)) is None
    long = np.arange(100_000) * 1e-3
    at = thermal_overload_at(long, np.full_like(long, 0.26))
    assert at == pytest.approx(_trip_after(0.26), abs=1e-3)
    # a stall broken off in time cools down again and never trips
    short = np.where((t >= 0.5) & (t < 2.0), 1.0, 0.0)
    assert thermal_overload_at(t, short) is None


def test_a_close_command_further_past_the_object_squeezes_harder():
    """The servo alone (its own position loop): the push is the distance past the object."""
    forces = []
    for close in (38.0, 37.0, 36.0):
        r = arduino_grasp(PLANT, ACTUAL, None, GraspScenario(close_command_deg=close),
                          seeds=SEEDS)  # fmt: skip
        forces.append(r.holding_force_n)
    assert forces[0] < forces[1] < forces[2]
    stall = STALL_TORQUE_NM / GraspScenario().finger_lever_m
    assert forces == pytest.approx([0.4 * stall, 0.6 * stall, 0.8 * stall])


def test_an_integrating_loop_winds_up_to_a_full_stall_and_overloads():
    r = arduino_grasp(PLANT, ACTUAL, PAPER_TUNED, GraspScenario(), seeds=SEEDS, options=OPTIONS,
                      label="paper-tuned", gripper="arduino test2 (actual)")  # fmt: skip
    assert r.controller == "paper-tuned P=1 I=9 D=-0.001"
    assert r.gripper == "arduino test2 (actual)"
    assert 0.0 < r.time_to_grasp_s < 1.0
    assert r.holding_force_pct == pytest.approx(100.0)
    assert r.overload and r.overload_at_s is not None and not r.held
    assert r.time_to_grasp_s + 1.0 < r.overload_at_s < r.time_to_grasp_s + FULL_STALL_LIMIT_S + 0.5


def test_the_stepped_run_is_the_simulation_cores_run():
    """One physics step at a time, the trajectory is simulate()'s on the same reference, and
    the per-step signals add up to its counters: nothing re-implemented."""
    scenario = GraspScenario()
    run = simulate_grasp(PLANT, ACTUAL, PAPER_TUNED, scenario, options=OPTIONS, seeds=SEEDS)
    dist = ACTUAL.with_overrides({"mechanics": {"object_contact_deg": scenario.object_deg}})
    traj = simulate(PLANT, scenario.reference(PLANT.dt_s), PAPER_TUNED, dist, seeds=list(SEEDS),
                    randomize=True, pid_options=OPTIONS)  # fmt: skip
    assert np.array_equal(traj.y_true, run.jaw_deg)
    assert np.array_equal(traj.u, run.command_deg)
    dt = PLANT.dt_s
    assert traj.contact_s == pytest.approx(run.touching.sum(axis=1) * dt)  # only the object
    assert traj.stall_s == pytest.approx(run.stalled.sum(axis=1) * dt)
    mean_push = run.current_fraction.sum(axis=1) / run.touching.sum(axis=1)
    assert traj.force_proxy == pytest.approx(mean_push)


def test_summaries_over_runs_take_the_worst_case():
    """Two constructed runs: the slower grasp, the lower force, the earlier trip count."""
    scenario = GraspScenario(hold_s=1.0, grasp_s=0.5, required_force_n=1.0)
    t = np.arange(-100, 1500) * 1e-3
    force = np.zeros((2, len(t)))
    force[0, t >= 0.2] = 3.0
    force[1, t >= 0.3] = 1.5
    force[1, (t >= 0.3) & (t < 0.4)] = 0.5  # 90 % of the hold value only from 0.4 s
    touching = force > 0
    r = summarize_grasp(t, force, touching, scenario, stall_force=6.0, overload_at_s=[None, 1.2],
                        gripper="g", controller="c")  # fmt: skip
    assert r.time_to_grasp_s == pytest.approx(0.4)
    assert r.holding_force_n == pytest.approx(2.25) and r.holding_force_pct == pytest.approx(37.5)
    assert r.min_force_n == pytest.approx(1.5)
    assert r.overload and r.overload_at_s == pytest.approx(1.2) and not r.held
    alone = summarize_grasp(t, force[:1], touching[:1], scenario, stall_force=6.0,
                            overload_at_s=[None], gripper="g", controller="c")  # fmt: skip
    assert alone.held and alone.time_to_grasp_s == pytest.approx(0.2)
    # a run that diverged neither grasps nor holds
    bad = summarize_grasp(t, force[:1], touching[:1], scenario, stall_force=6.0,
                          overload_at_s=[None], gripper="g", controller="c",
                          valid=np.array([False]))  # fmt: skip
    assert math.isnan(bad.time_to_grasp_s) and not bad.held


def test_the_result_round_trips_through_its_dict_and_json_nulls():
    r = GraspResult("g", "c", math.nan, 1.0, 13.4, 0.5, False, None, False, 3.0, 0.25)
    d = r.as_dict()
    assert list(d) == ["gripper", "controller", "time_to_grasp_s", "holding_force_n",
                       "holding_force_pct", "min_force_n", "overload", "overload_at_s", "held",
                       "hold_s", "peak_heat"]  # fmt: skip
    back = GraspResult.from_dict({**d, "time_to_grasp_s": None})  # JSON writes NaN as null
    assert math.isnan(back.time_to_grasp_s)
    assert {k: v for k, v in back.as_dict().items() if k != "time_to_grasp_s"} == {
        k: v for k, v in d.items() if k != "time_to_grasp_s"
    }
    # a row stored before the heat was reported reads back without it
    old = {k: v for k, v in d.items() if k != "peak_heat"}
    assert math.isnan(GraspResult.from_dict(old).peak_heat)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"close_command_deg": 41.0},  # not past the object
        {"object_deg": 95.0},  # beyond the open angle
        {"close_command_deg": 95.0, "object_deg": None},  # opens instead of closing
        {"hold_s": 0.0},
        {"finger_lever_m": -0.05},
        {"required_force_n": math.nan},
    ],
)
def test_a_scenario_that_makes_no_sense_is_refused(kwargs):
    with pytest.raises(ValueError, match=r"GraspScenario|close command|object"):
        GraspScenario(**kwargs)


# ---- the PID's grasp mode, and the admission check -------------------------------------------


def test_the_heat_state_is_the_first_order_filter_over_the_trip_level():
    """A constant 20 % push from cold: x = 0.2^2 (1 - a^k) with a = exp(-dt / tau), over the
    trip 0.25^2: it settles at 0.64 of the trip and never trips."""
    t = np.arange(200_000) * 1e-3
    heat = thermal_state(t, np.full_like(t, 0.2))
    a = math.exp(-1e-3 / THERMAL_TIME_CONSTANT_S)
    k = np.arange(1, len(t) + 1)
    np.testing.assert_allclose(heat, 0.64 * (1 - a**k), rtol=1e-9)
    assert heat[-1] == pytest.approx(0.64, abs=2e-3)  # 200 s: 6.5 time constants
    assert thermal_overload_at(t, np.full_like(t, 0.2)) is None
    # at the trip level exactly when the criterion trips
    stall = np.ones(3000)
    at = thermal_overload_at(t[:3000], stall)
    assert at == pytest.approx(FULL_STALL_LIMIT_S)
    assert thermal_state(t[:3000], stall)[round(at / 1e-3) - 1] == pytest.approx(1.0)


@pytest.mark.parametrize("p", [29.0, 35.0])
def test_the_grasp_mode_holds_with_the_squeeze_force(p):
    """The P controller of the plain test above with 6 and 18 deg of push: with the mode, once
    the jaw has stood blocked for the dwell, the command is held 1 deg past the object (39 deg,
    up to the measurement filter's last 0.875^100 of the approach): 20 % of stall, 1.49 N, on
    every step of the hold window."""
    scenario = GraspScenario()
    run = simulate_grasp(PLANT, FRICTIONLESS, PIDGains(p, 0.0, 0.0), scenario, options=GRASP)
    hold = run.t_s >= scenario.hold_window_s[0]
    np.testing.assert_allclose(run.command_deg[0, hold], 39.0, atol=1e-4)
    assert run.grasping[0, hold].all()
    r = run.result("g", "c")
    expected = 0.2 * STALL_TORQUE_NM / scenario.finger_lever_m
    assert r.min_force_n == pytest.approx(expected, rel=1e-4)
    assert r.holding_force_n == pytest.approx(expected, rel=1e-4)
    assert r.held and not r.overload
    assert 0.0 < r.peak_heat < 0.64


def test_with_the_mode_every_seed_of_the_actual_gripper_holds_without_tripping():
    plain = arduino_grasp(PLANT, ACTUAL, PAPER_TUNED, GraspScenario(), seeds=SEEDS,
                          options=OPTIONS)  # fmt: skip
    mode = arduino_grasp(PLANT, ACTUAL, PAPER_TUNED, GraspScenario(), seeds=SEEDS,
                         options=GRASP)  # fmt: skip
    assert not plain.held and plain.overload and plain.peak_heat >= 1.0
    assert mode.held and not mode.overload and mode.peak_heat < 0.5
    assert mode.min_force_n == pytest.approx(0.2 * STALL_TORQUE_NM / 0.05)
    assert mode.time_to_grasp_s < plain.time_to_grasp_s


def test_the_admission_check_gives_held_and_the_margins():
    gains = [[1.0, 9.0, -0.001], [3.432, 67.52, -0.008661]]
    plain = grasp_admission(gains, OPTIONS, PLANT, ACTUAL, SEEDS)
    mode = grasp_admission(gains, GRASP, PLANT, ACTUAL, SEEDS)
    assert not plain.held.any() and plain.reason == ("overload", "overload")
    assert np.all(plain.heat_margin < 0) and np.all(plain.margin < 0)
    assert mode.held.all() and mode.reason == ("", "")
    # the force margin: 1 deg of push, 20 % of 7.45 N, over the required 1 N
    np.testing.assert_allclose(mode.force_margin, 0.2 * STALL_TORQUE_NM / 0.05 - 1.0)
    assert np.all(mode.heat_margin > 0) and np.all(mode.margin > 0)
    assert mode.held_runs.shape == (2, len(SEEDS)) and mode.seeds == SEEDS
    # the hold would settle at (0.2 / 0.25)^2 of the trip; the plain PID at full stall, 16 x
    np.testing.assert_allclose(mode.steady_heat, 0.64)
    np.testing.assert_allclose(plain.steady_heat, 1.0 / 0.25**2)
    # one batch gives what each gain set gives alone, and what the summary of its runs says
    alone = grasp_admission([gains[1]], GRASP, PLANT, ACTUAL, SEEDS)
    np.testing.assert_array_equal(alone.peak_heat[0], mode.peak_heat[1])
    np.testing.assert_array_equal(alone.min_force_n[0], mode.min_force_n[1])
    r = arduino_grasp(PLANT, ACTUAL, PIDGains(*gains[1]), GraspScenario(), seeds=SEEDS,
                      options=GRASP)  # fmt: skip
    assert r.min_force_n == pytest.approx(mode.min_force_n[1].min())
    assert r.peak_heat == pytest.approx(mode.peak_heat[1].max())
    assert r.time_to_grasp_s == pytest.approx(mode.time_to_grasp_s[1])


def test_the_admission_check_takes_options_per_gain_set_and_batches_beyond_one_chunk():
    seeds = list(range(100000, 100009))  # 2 x 9 = 18 runs: two serial chunks
    hw = [-0.5, -3.6, 0.000186]
    mixed = grasp_admission(
        [[1.0, 9.0, -0.001], hw], [GRASP, dataclasses.replace(GRASP, sign=-1)], PLANT, ACTUAL, seeds
    )
    assert mixed.held_runs.shape == (2, 9)
    # the paper's hardware gains are slow: on some seeds the jaw reaches the object after the
    # hold window opens (1 s), which the check names
    assert mixed.held[0] and not mixed.held[1] and mixed.reason[1] == "force"
    assert mixed.force_margin[1] == -1.0
    with pytest.raises(ValueError, match="2 PID options for 1 gain sets"):
        grasp_admission([hw], [GRASP, GRASP], PLANT, ACTUAL, seeds)

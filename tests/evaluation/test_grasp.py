"""The grasp-and-hold scenario (gripper_env.evaluation.grasp) against hand-worked cases."""

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
    simulate_grasp,
    stall_force_n,
    summarize_grasp,
    thermal_overload_at,
)
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
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
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
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
    r = GraspResult("g", "c", math.nan, 1.0, 13.4, 0.5, False, None, False, 3.0)
    d = r.as_dict()
    assert list(d) == ["gripper", "controller", "time_to_grasp_s", "holding_force_n",
                       "holding_force_pct", "min_force_n", "overload", "overload_at_s", "held",
                       "hold_s"]  # fmt: skip
    back = GraspResult.from_dict({**d, "time_to_grasp_s": None})  # JSON writes NaN as null
    assert math.isnan(back.time_to_grasp_s)
    assert {k: v for k, v in back.as_dict().items() if k != "time_to_grasp_s"} == {
        k: v for k, v in d.items() if k != "time_to_grasp_s"
    }


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

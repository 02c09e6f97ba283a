"""The admission rule: the worst case over the stop range, the constraint values, the judge's
messages, and the searches' back-off."""

import math

import numpy as np
import pytest

from gripper_env.evaluation.admission import (
    Admission,
    checks_of_runs,
    nearest_stops_deg,
    shift_stops,
)
from gripper_env.evaluation.objective import load_objective
from gripper_env.evaluation.scoring import GainScorer, Task
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference

ACTUAL = load_disturbance("actual")
OBJECTIVE = load_objective()
LIMITS = OBJECTIVE.constraints.limits()


def test_the_nearest_stops_the_preset_can_draw():
    # actual.yaml: stops at 12 and 100 deg, drawn in 9-15 and 97-103
    assert nearest_stops_deg(ACTUAL) == (15.0, 97.0)
    assert nearest_stops_deg(ACTUAL, randomize=False) == (12.0, 100.0)
    assert nearest_stops_deg(load_disturbance("ideal")) == (-math.inf, math.inf)
    moved = shift_stops(ACTUAL, 3.0)
    assert moved.mechanics.limits_deg == (9.0, 103.0)
    assert moved.randomize["mechanics.limits_deg.0"] == (6.0, 12.0)
    assert nearest_stops_deg(moved) == (12.0, 100.0)
    assert moved.randomize["friction.S_deg"] == ACTUAL.randomize["friction.S_deg"]


def _runs(jaw_min, jaw_max, contact=0.0, settle=0.5, stall=0.0):
    n = len(jaw_min)
    return checks_of_runs(grip_settling_s=[settle] * n, ungrip_settling_s=[settle] * n,
                          stable=[True] * n, jaw_min_deg=jaw_min, jaw_max_deg=jaw_max,
                          stall_s=[stall] * n, contact_s=[contact] * n, k=1,
                          stops_deg=(15.0, 97.0))  # fmt: skip


def test_the_envelope_is_held_against_the_nearest_stop_not_the_drawn_one():
    """A jaw that reaches 14 deg touched no stop on a run that drew 10 deg, but the preset can
    draw 15: refused, 1 deg past it. One at 16 deg is admitted with 1 deg to spare."""
    past = Admission.build(LIMITS, checks=_runs([14.0, 20.0], [92.0, 93.0]))
    assert not past.feasible[0] and past.missed(0) == ["stop_clearance"]
    assert past.values["stop_clearance"][0] == pytest.approx(1.0)
    assert "1 deg past the nearest closed stop" in past.reason(0)
    inside = Admission.build(LIMITS, checks=_runs([16.0, 20.0], [96.5, 93.0]))
    assert inside.feasible[0] and inside.reason(0) is None
    assert inside.details["clearance_deg"][0] == pytest.approx(0.5)  # the open side, 96.5
    assert inside.details["closest_side"][0] == "open"
    assert inside.violation[0] == 0.0


def test_unsettled_and_stalled_runs_are_refused():
    never = Admission.build(LIMITS, checks=_runs([20.0], [92.0], settle=math.inf))
    assert never.missed(0) == ["settled"] and "never settle" in never.reason(0)
    stall = Admission.build(LIMITS, checks=_runs([20.0], [92.0], stall=0.04))
    assert stall.missed(0) == ["stall"] and "0.04 s" in stall.reason(0)


def test_robustness_values_and_binding():
    a = Admission.build(LIMITS, ms=np.array([1.5, 1.8, 3.0]), gm_db=np.array([9.0, 7.0, 2.0]),
                        loop_stable=np.array([True, True, False]),
                        spectral_radius=np.array([0.9, 0.95, 1.2]))  # fmt: skip
    assert list(a.feasible) == [True, False, False]
    assert a.values["ms"][1] == pytest.approx(0.2) and a.binding(1) == "ms"
    assert a.binding(2) == "stability" and "spectral radius 1.2" in a.reason(2)
    assert a.violation[1] == pytest.approx(0.2 / 1.6)
    assert a.violation[2] > a.violation[1]


def test_a_sampled_stop_misses_what_the_rule_catches():
    """Independent truth from the trajectories: a gain set whose jaw passes 15 deg touches its
    drawn stop on some seeds only; the rule refuses it on the nearest stop the preset can
    draw, whatever the seeds."""
    plant = load_plant("test2")
    ref = load_reference("step", plant.dt_s)
    opts = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
    task = Task.build(plant, ref, ACTUAL, np.arange(12), objective=OBJECTIVE, options=opts)
    scorer = GainScorer(task)
    gains = np.array([[0.6925, 17.78, -0.0063, 100.0]])  # overshoots the grip to ~14.5 deg
    s = scorer.score(gains, keep_trajectory=True)
    low = s.trajectory.y_true.min(axis=1)
    untouched_but_past = (np.asarray(s.metrics.run["contact_s"]) == 0) & (low < 15.0)
    assert untouched_but_past.any()  # the sampled stops alone would let this run pass
    assert not s.feasible[0] and "stop_clearance" in s.admission.missed(0)
    assert s.admission.details["jaw_min_deg"][0] == pytest.approx(low.min())


def test_a_search_holds_the_jaw_further_in_than_the_judge():
    c = OBJECTIVE.constraints
    assert c.limits(search=True)["stop_clearance_deg"] == pytest.approx(
        c.stop_clearance_deg + c.search_backoff_deg
    )
    checks = _runs([15.5], [92.0])  # 0.5 deg inside the nearest stop
    assert Admission.build(c.limits(), checks=checks).feasible[0]
    assert not Admission.build(c.limits(search=True), checks=checks).feasible[0]
    assert c.measured_gm_min_db == pytest.approx(20 * math.log10(1.6 / 0.6))


def test_the_grasp_is_a_constraint_of_the_rule():
    """With the grasp mode a PID holds the object; the plain PID's integrator winds up against
    it and trips the servo: refused, with the reason (gripper_env.evaluation.grasp's verdict)."""
    plant = load_plant("test2")
    ref = load_reference("step", plant.dt_s)
    gains = np.array([[2.4, 39.0, 0.0, 100.0]])
    verdicts = {}
    for name, grasp in (("mode", True), ("plain", False)):
        opts = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping",
                          **({} if grasp else {"grasp": None}))  # fmt: skip
        task = Task.build(plant, ref, ACTUAL, [0, 1], objective=OBJECTIVE, options=opts)
        verdicts[name] = GainScorer(task).score(gains).admission
    assert OBJECTIVE.constraints.grasp
    mode, plain = verdicts["mode"], verdicts["plain"]
    assert mode.feasible[0] and mode.values["grasp"][0] < 0.0  # held, with a margin
    assert plain.missed(0) == ["grasp"] and plain.values["grasp"][0] == 1.0
    assert "trips the servo's thermal limit on test2" in plain.reason(0)


def test_a_policys_grasp_joins_its_admission_row():
    from gripper_env.evaluation.admission import with_grasp

    row = Admission.build(LIMITS, checks=_runs([20.0], [92.0])).row(0)
    kept = with_grasp(row, 0.0, "")
    assert kept["admitted"] and kept["constraints"]["grasp"] == 0.0
    lost = with_grasp(row, 0.3, "overload on test4")
    assert not lost["admitted"] and lost["missed"] == ["grasp"]
    assert "trips the servo's thermal limit on test4 (30 % of its grasp runs)" in lost["reason"]

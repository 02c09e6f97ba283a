"""A loaded joint's load from its records: the plan's safety checks, and the fit recovering a
known payload within its stated uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.model.so101_arm import joint_model, load_arm
from gripper_env.sysid.bus_experiments import simulate_record
from gripper_env.sysid.bus_load import (
    POSE_SPREAD_DEG,
    check_load_plan,
    identify_load,
    load_plan,
    load_settings,
)

SERVO = load_bus_servo("sts3215")
LEROBOT = SERVO.community["lerobot"].model_copy(update={"torque_limit": 1000})


def test_plan_stays_near_the_held_pose():
    plan = load_plan(185.0)
    assert np.min(plan.goals_deg) >= 185.0 - POSE_SPREAD_DEG - 5.0
    assert np.max(plan.goals_deg) <= 185.0 + POSE_SPREAD_DEG + 5.0
    assert plan.goals_deg[0] == 185.0


def test_unsafe_plans_are_refused_before_anything_is_sent():
    prior = joint_model(SERVO, "elbow_flex", {}, payload_range_kg=(0.0, 0.1))
    plan = load_plan(180.0)
    settings = load_settings(LEROBOT)
    check_load_plan(plan, (90.0, 270.0), prior, settings)  # safe: nothing raised
    with pytest.raises(ValueError, match="outside the calibrated"):
        check_load_plan(plan, (175.0, 270.0), prior, settings)
    weak = [r.model_copy(update={"torque_limit": 400}) for r in settings]
    with pytest.raises(ValueError, match="torque limit 400"):  # 0.74 N m > 60 % of 0.76 N m
        check_load_plan(plan, (90.0, 270.0), prior, weak)
    low = SERVO.protection.model_copy(update={"overload_duty": 0.3})
    touchy = joint_model(SERVO.with_updates(protection=low), "elbow_flex", {},
                         payload_range_kg=(0.0, 0.1))  # fmt: skip
    with pytest.raises(ValueError, match="overload threshold"):
        check_load_plan(plan, (90.0, 270.0), touchy, settings)


@pytest.mark.parametrize("payload", [0.0, 0.07])
def test_fit_recovers_the_payload(payload):
    """Records of the elbow with a known payload (the truth: the family's servo with the
    published links), the fit started from a 50 g guess: the payload within 3 standard errors
    and 5 g, the amplitude within 2 %."""
    truth = joint_model(SERVO, "elbow_flex", {}, payload_kg=payload)
    plan = load_plan(180.0)
    rng = np.random.default_rng(1)
    records = [simulate_record(truth, r, plan, rng=rng) for r in load_settings(LEROBOT)]
    links = load_arm().joint_load("elbow_flex", {}, payload_kg=0.0)
    est = identify_load(records, SERVO, links.with_payload(0.05), links=links)
    got, std = est.values["payload_kg"], est.std["payload_kg"]
    assert abs(got - payload) <= max(3 * std, 1e-4) and abs(got - payload) < 0.005
    amp, _ = truth.load.gravity()
    assert est.values["gravity_nm"] == pytest.approx(amp, rel=0.02)
    assert est.rmse_deg < 0.1

"""The load on an arm's joint: the sum of the links' and the payload's sinusoids, worked by
hand, and the SO-101's joint loads against the arm's own gravity torques."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gripper_env.model.bus_load import GRAVITY, JointLoad
from gripper_env.model.so101_arm import LOADED_JOINTS, load_arm, q_of_shaft, shaft_deg


def test_two_sinusoids_sum_to_one():
    """0.4 N m hanging at 270 deg plus 0.1 kg at 0.3 m hanging at 180 deg: the sum's
    amplitude and hang angle by hand (phasors 0.4 at 270 deg and 0.294 at 180 deg)."""
    load = JointLoad(joint="j", gravity_nm=0.4, hang_deg=270.0, inertia_kgm2=0.01,
                     payload_kg=0.1, payload_lever_m=0.3, payload_hang_deg=180.0)  # fmt: skip
    b = 0.1 * GRAVITY * 0.3
    amp, hang = load.gravity()
    assert amp == pytest.approx(math.hypot(0.4, b))
    assert hang == pytest.approx(math.degrees(math.atan2(-0.4, -b)))
    for theta in (0.0, 45.0, 200.0, 300.0):
        want = -0.4 * math.sin(math.radians(theta - 270)) - b * math.sin(math.radians(theta - 180))
        assert load.torque_nm(theta) == pytest.approx(want)
    assert load.inertia() == pytest.approx(0.01 + 0.1 * 0.3**2)


def test_worst_torque_over_a_span_and_the_payloads():
    load = JointLoad(joint="j", gravity_nm=0.4, hang_deg=270.0, inertia_kgm2=0.0,
                     payload_range_kg=(0.0, 0.1), payload_lever_m=0.3,
                     payload_hang_deg=270.0)  # fmt: skip
    top = 0.4 + 0.1 * GRAVITY * 0.3
    assert load.worst_torque_nm((150.0, 200.0)) == pytest.approx(top)  # horizontal at 180
    # near hanging (260-280 deg) the torque is small: at most at the span's ends
    assert load.worst_torque_nm((260.0, 280.0)) == pytest.approx(top * math.sin(math.radians(10)))
    with pytest.raises(ValueError, match="payload_range_kg"):
        JointLoad(joint="j", gravity_nm=0, hang_deg=0, inertia_kgm2=0, payload_range_kg=(1, 0))


@pytest.mark.parametrize("joint", LOADED_JOINTS)
def test_joint_load_is_the_arms_torque_at_every_angle(joint):
    """With the others held, the links beyond turn as one body: the joint load's sinusoid is
    the arm's gravity torque at every angle of the joint, payload included."""
    arm = load_arm()
    rng = np.random.default_rng(1)
    pose = {j: rng.uniform(*arm.joint_range(j)) for j in arm.joint_names}
    for payload in (0.0, 0.07):
        load = arm.joint_load(joint, pose, payload_kg=payload)
        for q in rng.uniform(*arm.joint_range(joint), size=5):
            want = arm.gravity_torques({**pose, joint: q}, payload)[joint]
            assert load.torque_nm(shaft_deg(q)) == pytest.approx(want, abs=1e-12)
            assert q_of_shaft(shaft_deg(q)) == pytest.approx(q)


def test_so101_elbow_load_from_the_published_masses():
    """The forearm, wrist and gripper (0.104 + 0.079 + 0.087 + 0.012 kg) horizontal at the
    calibrated middle: 0.45 N m on the elbow, a 100 g payload 0.29 m out adds 0.29 N m."""
    arm = load_arm()
    load = arm.joint_load("elbow_flex", {}, payload_kg=0.0)
    assert load.gravity_nm == pytest.approx(0.4528, abs=1e-3)
    assert abs(arm.gravity_torques({})["elbow_flex"]) == pytest.approx(0.4525, abs=1e-3)
    assert load.payload_lever_m == pytest.approx(0.294, abs=2e-3)
    assert arm.spec.source.startswith("TheRobotStudio/SO-ARM100")

"""The project's MJCF of the SO-101 (no meshes) cross-checks the load model: MuJoCo's gravity
force and mass matrix against the arm's hand-computed torques and inertias, and a loaded joint
run in MuJoCo (the exact runtime, the other joints fixed) against the simulation core's
one-joint load model."""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.model.so101_arm import LOADED_JOINTS, joint_model, load_arm
from gripper_env.mujoco.arm import arm_mjcf
from gripper_env.mujoco.runtime import ExactServo, step_servos
from gripper_env.sim.bus_servo import simulate_bus

mujoco = pytest.importorskip("mujoco")


@pytest.mark.parametrize("payload", [0.0, 0.1])
def test_gravity_and_inertia_are_mujocos(payload):
    """At random poses: MuJoCo's ``-qfrc_bias`` at rest is the arm's gravity torque on every
    joint, and its mass matrix's diagonal (less the servos' armature) the inertia about each
    axis of everything beyond it."""
    arm = load_arm()
    servo = load_bus_servo("sts3215")
    m = mujoco.MjModel.from_xml_string(arm_mjcf(servo, payload_kg=payload))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(2)
    full = np.zeros((m.nv, m.nv))
    for _ in range(5):
        pose = {j: rng.uniform(*arm.joint_range(j)) for j in arm.joint_names}
        for i, j in enumerate(arm.joint_names):
            d.qpos[m.jnt_qposadr[i]] = pose[j]
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, full)
        mine = arm.gravity_torques(pose, payload)
        for i, j in enumerate(arm.joint_names):
            assert -d.qfrc_bias[i] == pytest.approx(mine[j], abs=1e-9)
            inertia = full[i, i] - m.dof_armature[i]
            # the payload body carries 1e-9 kg m^2 of its own (MuJoCo wants a body inertia)
            assert inertia == pytest.approx(arm.axis_inertia(j, pose, payload), rel=1e-6, abs=1e-8)


@pytest.mark.parametrize("joint", LOADED_JOINTS)
def test_loaded_joint_in_mujoco_is_the_cores(joint):
    """LeRobot's registers (P 16, D 32) holding a pose against gravity, then steps of -20 and
    +10 deg, with and without 100 g: MuJoCo's arm (the joint's exact runtime, the other joints
    fixed at the pose) and the core's one-joint load model agree within a tick RMS, and sag alike
    (2-8 deg at P = 16)."""
    arm = load_arm()
    servo = load_bus_servo("sts3215")
    regs = servo.community["lerobot"].model_copy(update={"torque_limit": 1000})
    pose = {"shoulder_lift": -0.6, "elbow_flex": 0.4, "wrist_flex": 0.2}
    for payload in (0.0, 0.1):
        jm = joint_model(servo, joint, pose, payload_kg=payload, arm=arm)
        held = jm.jaw.open_deg
        goal = np.concatenate(
            [np.full(800, held), np.full(1200, held - 20), np.full(1200, held + 10)]
        )
        core = simulate_bus(jm, regs, goal).position[0] * jm.deg_per_tick
        xml = arm_mjcf(servo, payload_kg=payload, pose=pose, free=[joint], arm=arm)
        m = mujoco.MjModel.from_xml_string(xml)
        d = mujoco.MjData(m)
        d.qpos[0] = pose[joint]
        mujoco.mj_forward(m, d)
        sv = ExactServo(m, d, servo, regs, joint=joint, actuator=joint, zero_deg=180.0)
        got = sv.run(goal) * jm.deg_per_tick
        assert np.sqrt(np.mean((got - core) ** 2)) < jm.deg_per_tick, (joint, payload)
        assert abs(got[790] - core[790]) <= 2 * jm.deg_per_tick  # the held pose's sag


def test_neighbours_held_by_their_servos_couple_in():
    """Every joint on its own servo (LeRobot's P 16): the shoulder sags under the arm's weight,
    which turns the elbow's load, and the elbow's hold differs from the one-joint model's
    (neighbours fixed) by more than a tick: what the one-joint model leaves out."""
    arm = load_arm()
    servo = load_bus_servo("sts3215")
    regs = servo.community["lerobot"].model_copy(update={"torque_limit": 1000})
    m = mujoco.MjModel.from_xml_string(arm_mjcf(servo, payload_kg=0.1))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    servos = [ExactServo(m, d, servo, regs, joint=j, actuator=j, zero_deg=180.0)
              for j in arm.joint_names]  # fmt: skip
    for _ in range(1500):
        step_servos(servos)
    lift, elbow = servos[1], servos[2]
    assert abs(lift.angle_deg - 180.0) > 3.0  # the shoulder sagged
    jm = joint_model(servo, "elbow_flex", {}, payload_kg=0.1, arm=arm)
    alone = simulate_bus(jm, regs, np.full(1500, 180.0)).position[0, -1] * jm.deg_per_tick
    assert abs(elbow.angle_deg - alone) > jm.deg_per_tick

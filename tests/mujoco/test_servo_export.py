"""The exported servo in MuJoCo: the native class's parameters by hand, the MJCF as MuJoCo
compiles it, the exact runtime's loop against the simulation core tick for tick, and the exact
runtime against the core on the recipe's profiles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.mujoco.runtime import ExactServo, RegisterLoop, installed
from gripper_env.mujoco.servo_class import native_servo, physical_terms, servo_mjcf
from gripper_env.mujoco.verify import recipe_profiles, rms_deg, run_core, run_exact
from gripper_env.sim import bus_servo as core
from gripper_env.sim.bus_servo import DT, simulate_bus

mujoco = pytest.importorskip("mujoco")


def test_native_class_by_hand():
    """STS3215 (1.91 N m stall, 312.5 deg/s no-load, tau_m 30 ms, Coulomb 5 %): the
    register mapping worked by hand."""
    m = load_bus_servo("sts3215")
    regs = RegisterSet(p=32, i=0, d=32, torque_limit=800)
    n = native_servo(m, regs)
    w0 = 312.5 * math.pi / 180  # rad/s
    assert n.armature == pytest.approx(1.91 * 0.03 / w0)  # 0.0105 kg m^2
    assert n.damping == pytest.approx(1.91 / w0)  # 0.350 N m s/rad
    assert n.frictionloss == pytest.approx(0.05 * 1.91)
    assert n.forcerange == pytest.approx(0.8 * 1.91)
    ticks_per_rad = 4096 / (2 * math.pi)
    assert n.kp == pytest.approx(1.91 * 2.6e-4 * 32 * ticks_per_rad)  # 10.36 N m/rad
    assert n.kv == pytest.approx(1.91 * 4.0e-3 * 32 * ticks_per_rad * 1e-3)
    assert n.delay_s == pytest.approx(0.002 + 0.004)  # goal delay + loop delay


@pytest.mark.parametrize("form", ["native", "exact"])
def test_mjcf_compiles_with_the_class(form):
    """MuJoCo loads the one-joint model; its compiled joint and actuator hold the class."""
    m = load_bus_servo("sts3215")
    regs = m.factory
    mm = mujoco.MjModel.from_xml_string(servo_mjcf(m, regs, form))
    t = physical_terms(m)
    assert mm.njnt == 1 and mm.nu == 1
    assert mm.dof_armature[0] == pytest.approx(t["armature"], rel=1e-5)
    assert mm.dof_damping[0] == pytest.approx(t["damping"], rel=1e-5)
    lo, hi = (math.radians(v) for v in m.jaw.limits_deg)
    assert mm.jnt_range[0] == pytest.approx([lo, hi], rel=1e-5)
    if form == "native":
        n = native_servo(m, regs)
        assert mm.dof_frictionloss[0] == pytest.approx(n.frictionloss, rel=1e-5)
        assert mm.actuator_gainprm[0, 0] == pytest.approx(n.kp, rel=1e-5)
        assert mm.actuator_biasprm[0, 1] == pytest.approx(-n.kp, rel=1e-5)
        assert mm.actuator_biasprm[0, 2] == pytest.approx(-n.kv, rel=1e-5)
        assert mm.actuator_forcerange[0] == pytest.approx([-n.forcerange, n.forcerange])
        assert mm.actuator_delay[0] == pytest.approx(n.delay_s)
    else:
        assert mm.actuator_gear[0, 0] == pytest.approx(1.91)
        assert mm.actuator_ctrlrange[0] == pytest.approx([-1.0, 1.0])


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_register_loop_replays_the_core(family):
    """The core's encoder readings fed through the runtime's loop give the core's duties, tick
    for tick: profile (acceleration), dead band, integrator and its clamp, output limit, delays,
    and the protection (an overload trip against a stop and its protective torque)."""
    m = load_bus_servo(family)
    sts = family == "sts3215"
    regs = m.factory.model_copy(update={"i": 3 if sts else 300, "acceleration": 20 if sts else 5})
    open_deg, closed = m.jaw.open_deg, m.jaw.limits_deg[0]
    goal = np.concatenate([np.full(300, open_deg - 20), np.full(4200, closed - 10)])
    run = simulate_bus(m, regs, goal, start_deg=open_deg)
    assert run.trip[0, -1] == core.TRIP_OVERLOAD  # the hold against the stop trips it
    loop = RegisterLoop(m, regs, open_deg)
    lag = round(m.physics.loop_delay_s / DT)
    for k in range(goal.size):
        torque = run.torque[0, k - 1] if k else 0.0
        meas, acting = loop.tick(run.position[0, k] * m.deg_per_tick, torque, goal[k])
        assert meas == run.position[0, k]
        assert loop.duty == pytest.approx(run.duty[0, k], abs=1e-12), k
        assert acting == pytest.approx(run.duty[0, k - lag] if k >= lag else 0.0, abs=1e-12)
    assert loop.first_trip == core.TRIP_OVERLOAD


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_exact_runtime_follows_the_core(family):
    """The same model in MuJoCo's joint with the runtime's loop and Karnopp friction, integrated
    as the core integrates (semi-implicit Euler at 1/8 ms): within a twentieth of an encoder
    tick (RMS) of the core on the recipe's steps and creep and the tuner's tracking steps (the
    gear's play included on the STS3215): the same ticks but for a rare one."""
    m = load_bus_servo(family)
    for name, goal in recipe_profiles(m).items():
        err = rms_deg(run_exact(m, m.factory, goal), run_core(m, m.factory, goal))
        assert err < m.deg_per_tick / 20, (name, err)


def test_register_change_carries_over():
    """Registers written mid-run act from the next tick, as in the core run in two parts with
    the state carried: no refit, the same response (to a tick)."""
    m = load_bus_servo("xl330")
    a, b = m.factory, m.factory.model_copy(update={"p": 1200, "d": 1500})
    goal = recipe_profiles(m)["tracking"]
    half = goal.size // 2
    params = core.bus_params(m)[None]
    state = core.bus_state(m, goal[0])[None].copy()
    ticks = np.round(goal / m.deg_per_tick)
    lag = round(m.physics.delay_s / DT)
    ticks = np.concatenate([np.full(lag, ticks[0]), ticks[:-lag]])
    first = core.run_bus(params, core.bus_registers(m, a)[None], state, ticks[None, :half])
    second = core.run_bus(params, core.bus_registers(m, b)[None], state, ticks[None, half:])
    want = np.concatenate([first.position[0], second.position[0]]) * m.deg_per_tick
    mm = mujoco.MjModel.from_xml_string(servo_mjcf(m, a, "exact"))
    d = mujoco.MjData(mm)
    d.qpos[0] = math.radians(goal[0])
    mujoco.mj_forward(mm, d)
    servo = ExactServo(mm, d, m, a)
    got = list(servo.run(goal[:half]))
    servo.set_registers(b)
    got += list(servo.run(goal[half:]))
    # within an encoder tick (RMS): where the jaw sticks in its dead band differs by a tick
    assert rms_deg(np.array(got) * m.deg_per_tick, want) < m.deg_per_tick
    # and the new gains changed the response: the first part alone under b differs
    only_b = run_core(m, b, goal)
    assert rms_deg(only_b[:half], want[:half]) > 3 * m.deg_per_tick


def test_mjcb_control_drives_the_loop():
    """Inside the user's own mj_step loop (mjcb_control): the loop runs once per 1 ms tick and
    the horn ends each step within the dead band of the core's end."""
    m = load_bus_servo("sts3215")
    mm = mujoco.MjModel.from_xml_string(servo_mjcf(m, m.factory, "exact"))
    d = mujoco.MjData(mm)
    d.qpos[0] = math.radians(m.jaw.open_deg)
    mujoco.mj_forward(mm, d)
    servo = ExactServo(mm, d, m, m.factory)
    goal = m.jaw.open_deg - 30.0
    servo.goal_deg = goal
    with installed([servo]):
        for _ in range(round(0.6 / mm.opt.timestep)):
            mujoco.mj_step(mm, d)
    core_end = run_core(m, m.factory, np.r_[m.jaw.open_deg, np.full(600, goal)])[-1]
    assert servo.angle_deg == pytest.approx(core_end, abs=0.5)
    assert abs(servo.angle_deg - goal) < 1.0

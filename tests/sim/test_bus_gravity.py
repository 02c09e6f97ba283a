"""The bus-servo block with a load (an arm's joint): inert without one, a free swing against
an independent integration of the pendulum, and the hold's sag against the friction band."""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from gripper_env.model.bus_load import JointLoad
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.sim import bus_servo as core
from gripper_env.sim.bus_servo import DT, simulate_bus


def test_no_load_and_a_zero_load_give_the_same_run():
    """A zero load leaves every trajectory bit-identical to no load."""
    m = load_bus_servo("sts3215")
    zero = m.with_updates(load=JointLoad(joint="j", gravity_nm=0.0, hang_deg=0.0,
                                         inertia_kgm2=0.0))  # fmt: skip
    goal = np.concatenate([np.full(300, 240.0), np.full(900, 200.0)])
    a, b = simulate_bus(m, m.factory, goal), simulate_bus(zero, m.factory, goal)
    for name in ("position", "duty", "torque", "temperature"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert core.bus_params(m)[core.PB_GRAV] == 0.0


def test_free_swing_matches_the_pendulum():
    """Torque off, no friction, no play: the joint falls as ``J th'' = -b th' - A sin(th - h)``
    (the motor's back-EMF damping ``b``, the inertia the motor's plus the load's), integrated
    independently with scipy."""
    m = load_bus_servo("sts3215")
    m = m.with_updates(physics=m.physics.model_copy(
        update={"coulomb": 0.0, "static": 0.0, "backlash_deg": 0.0, "loop_delay_s": 0.0}
    ))  # fmt: skip
    load = JointLoad(joint="j", gravity_nm=0.5, hang_deg=200.0, inertia_kgm2=0.01)
    m = m.with_updates(load=load, jaw=m.jaw.model_copy(update={"limits_deg": (0.0, 360.0)}))
    ph = m.physics
    w0 = math.radians(ph.omega0_deg_s)
    j = ph.stall_torque_nm * ph.tau_m_s / w0 + 0.01
    b = ph.stall_torque_nm / w0
    n = 1500
    params = core.bus_params(m)[None]
    regs = core.bus_registers(m, RegisterSet(p=0, torque_limit=0), torque_on=False)[None]
    state = core.bus_state(m, 240.0)[None].copy()
    state[0, core.SB_STUCK] = 0.0
    run = core.run_bus(params, regs, state, np.zeros((1, n)))

    def rhs(_t: float, x: np.ndarray) -> list[float]:
        th, w = x
        return [w, (-b * w - 0.5 * math.sin(th - math.radians(200.0))) / j]

    t = np.arange(n) * DT
    ref = solve_ivp(rhs, (0, t[-1]), [math.radians(240.0), 0.0], t_eval=t, rtol=1e-9,
                    atol=1e-12).y[0]  # fmt: skip
    got = run.position[0] * m.deg_per_tick
    assert np.max(np.abs(got - np.degrees(ref))) < 0.2  # the encoder's tick, and 1/8 ms Euler
    assert got[-1] < 206.0  # the back-EMF damps it: it creeps down towards the hang angle


def test_hold_sags_by_the_load_over_the_gain():
    """Holding against gravity, the loop stops where ``kp P e`` balances the load within the
    static friction: ``|kp P e - A sin(th - h) / T_s| <= static`` (fractions of stall)."""
    m = load_bus_servo("sts3215")
    load = JointLoad(joint="j", gravity_nm=0.6, hang_deg=270.0, inertia_kgm2=0.008)
    jaw = m.jaw.model_copy(update={"open_deg": 180.0, "limits_deg": (90.0, 270.0)})
    m = m.with_updates(load=load, jaw=jaw)
    for p in (16, 32, 64):
        regs = RegisterSet(p=p, i=0, d=32, torque_limit=1000)
        run = simulate_bus(m, regs, np.full(2000, 180.0), start_deg=180.0)
        y = run.position[0, -1] * m.deg_per_tick
        e_ticks = 180.0 / m.deg_per_tick - run.position[0, -1]
        grav = 0.6 * math.sin(math.radians(y - 270.0)) / m.physics.stall_torque_nm
        assert abs(m.scale.kp * p * e_ticks - grav) <= m.physics.static + m.scale.kp * p
        assert e_ticks < 0  # the load pushes the joint up (towards 270 - 180): it sags there

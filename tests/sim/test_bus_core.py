"""The bus servo block of the simulation core against independent truth: python-control's
response of the linear loop, the dead band static friction leaves, the protections' timers."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.sim import bus_servo as core
from gripper_env.sim.bus_servo import DT, simulate_bus


def _frictionless(family: str = "sts3215", lag_s: float = 0.0):
    m = load_bus_servo(family)
    physics = m.physics.model_copy(  # and no gear play: the loop is linear
        update={
            "coulomb": 0.0, "static": 0.0, "delay_s": 0.0, "loop_delay_s": lag_s,
            "backlash_deg": 0.0,
        }
    )  # fmt: skip
    return m.with_updates(physics=physics)


@pytest.mark.parametrize("lag_s", [0.0, 0.003])
def test_linear_loop_matches_python_control(lag_s):
    """No friction, no saturation: the step response is the discrete loop's (ZOH motor and jaw,
    PD in register units, one tick of computation delay plus the loop's own), to the encoder's
    quantisation."""
    m = _frictionless(lag_s=lag_s)
    regs = RegisterSet(p=8, i=0, d=2, torque_limit=1000)  # D small: no derivative kick saturates
    n = 800
    goal = np.full(n, m.jaw.open_deg - 3.0)
    run = simulate_bus(m, regs, goal, start_deg=m.jaw.open_deg)
    assert np.max(np.abs(run.duty)) < 1.0  # linear: never saturated
    y = (run.position[0] - run.position[0, 0]) * m.deg_per_tick
    # python-control: motor+jaw omega0 / (s (tau s + 1)) deg per duty, ZOH at 1 ms
    plant = ct.sample_system(
        ct.tf([m.physics.omega0_deg_s], [m.physics.tau_m_s, 1.0, 0.0]), DT, method="zoh"
    )
    z = ct.tf([1.0, 0.0], [1.0], DT)
    kp, kd = m.scale.kp * regs.p, m.scale.kd * regs.d
    pd = kp + kd * (1 - 1 / z)
    lag = round(lag_s / DT)
    loop = pd * plant / m.deg_per_tick * (1 / z) ** (1 + lag)
    closed = ct.feedback(loop, 1)
    ref = -3.0 / m.deg_per_tick
    _, yref = ct.forced_response(closed, T=np.arange(n) * DT, U=np.full(n, ref))
    # the encoder rounds to a tick (and the goal too); the loop acts on the rounded error
    assert np.max(np.abs(y / m.deg_per_tick - yref)) < 3.0


def test_dead_band_shrinks_as_one_over_p():
    """With static friction the jaw stops where ``kp P e`` no longer beats it: the settled error
    is at most ``static / (kp P)`` ticks, and halves as P doubles (the community's measurement:
    P = 16 reaches less of a small step than P = 32)."""
    m = load_bus_servo("sts3215")
    m = m.with_updates(physics=m.physics.model_copy(update={"loop_delay_s": 0.0}))
    errors = []
    for p in (8, 16, 32):
        regs = RegisterSet(p=p, i=0, d=0, torque_limit=1000)
        goal = np.full(1500, m.jaw.open_deg - 4.0)
        run = simulate_bus(m, regs, goal, start_deg=m.jaw.open_deg)
        err = abs(round((m.jaw.open_deg - 4.0) / m.deg_per_tick) - run.position[0, -1])
        bound = m.physics.static / (m.scale.kp * p)
        assert err <= bound + 1, (p, err, bound)
        errors.append(err)
    assert errors[0] > errors[1] > errors[2]


def test_overload_trips_after_its_time_and_the_sts_keeps_protective_torque():
    m = load_bus_servo("sts3215")
    goal = np.concatenate([np.full(200, m.jaw.open_deg), np.full(4000, m.jaw.limits_deg[0])])
    run = simulate_bus(m, m.factory, goal, with_object=True)
    duty = np.abs(run.duty[0])
    over = duty >= m.protection.overload_duty - 1e-12
    first = int(np.argmax(run.trip[0] > 0))
    # the timer counts up above the threshold and down (to zero) below it: it trips at
    # overload_time_s
    timer, trip_at = 0, None
    for k, o in enumerate(over):
        timer = timer + 1 if o else max(timer - 1, 0)
        if timer * DT >= m.protection.overload_time_s - 1e-9:
            trip_at = k
            break
    assert trip_at is not None and first == trip_at and run.trip[0, first] == core.TRIP_OVERLOAD
    assert np.max(duty[first + 10 :]) <= m.protection.tripped_duty + 1e-12


def test_torque_off_does_not_move_and_the_object_stops_the_jaw():
    m = load_bus_servo("xl330")
    goal = np.full(1000, m.jaw.limits_deg[0])
    params = core.bus_params(m, with_object=True)[None]
    regs = core.bus_registers(m, m.factory, torque_on=False)[None]
    state = core.bus_state(m)[None]
    run = core.run_bus(params, regs, state, np.round(goal / m.deg_per_tick))
    assert np.all(run.position[0] == run.position[0, 0]) and np.all(run.duty == 0)
    run = simulate_bus(m, m.factory, goal, with_object=True, start_deg=m.jaw.open_deg)
    closest = run.position[0, -1] * m.deg_per_tick
    # the object is a stiff spring: pushed at full duty it gives 1 / stiffness deg
    assert m.jaw.object_deg - 1.0 / m.jaw.contact_stiffness - 0.2 < closest < m.jaw.object_deg


def test_bad_batches_are_refused():
    m = load_bus_servo("sts3215")
    p = core.bus_params(m)[None]
    r = core.bus_registers(m, m.factory)[None]
    s = core.bus_state(m)[None]
    with pytest.raises(ValueError, match="finite"):
        core.run_bus(p, r, s, np.array([np.nan, 1.0]))
    with pytest.raises(ValueError, match="batch sizes differ"):
        core.run_bus(np.repeat(p, 2, axis=0), r, s, np.zeros(3))


def test_backlash_is_a_play_operator_closed_by_the_object():
    """Hand-worked: a 1 deg gap (half 0.5). Free of contact, the jaw stays where it is while the
    motor side moves inside the gap, and is dragged by its far edge beyond it. Pressed on an
    object at duty u without friction, the jaw settles where the spring balances u, obj - u / k,
    with or without the gap; the motor side sits half a gap behind it."""
    free = dict(lo=-1e9, hi=1e9, obj=-np.inf)
    th = 0.0
    for thm, expected in [(2.0, 1.5), (1.0, 1.5), (0.9, 1.4), (1.2, 1.4), (3.0, 2.5)]:
        th = core._output(thm, th, 0.5, free["lo"], free["hi"], free["obj"])
        assert th == pytest.approx(expected), (thm, th)
    m = load_bus_servo("sts3215")
    for gap in (0.0, 1.0):
        physics = m.physics.model_copy(update={"coulomb": 0.0, "static": 0.0, "backlash_deg": gap})
        mm = m.with_updates(physics=physics)
        regs = RegisterSet(p=32, i=0, d=32, torque_limit=300)  # saturated at u = 0.3
        run = simulate_bus(mm, regs, np.full(3000, mm.jaw.limits_deg[0]), with_object=True)
        x = mm.jaw.object_deg - 0.3 / mm.jaw.contact_stiffness
        assert run.force[0, -1] == pytest.approx(0.3, rel=1e-3)
        assert run.position[0, -1] * mm.deg_per_tick == pytest.approx(x, abs=mm.deg_per_tick)
    state = core.bus_state(mm)[None].copy()
    params = core.bus_params(mm, with_object=True)[None]
    goal = np.full((1, 3000), round(mm.jaw.limits_deg[0] / mm.deg_per_tick))
    core.run_bus(params, core.bus_registers(mm, regs)[None], state, goal)
    assert state[0, core.SB_TH] - state[0, core.SB_THM] == pytest.approx(0.5, abs=1e-9)

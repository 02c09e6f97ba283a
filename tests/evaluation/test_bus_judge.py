"""Judging bus-servo registers: the loop's margins against python-control, the scenarios'
measures on hand-checkable cases."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from gripper_env.evaluation.bus_servo import corner_models, hold_metrics, judge, loop_margins
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.sim.bus_servo import DT


def _ct_loop(m, regs, k_contact=0.0):
    ph, sc = m.physics, m.scale
    plant = ct.sample_system(
        ct.tf([1.0], [ph.tau_m_s / ph.omega0_deg_s, 1 / ph.omega0_deg_s, k_contact]), DT, "zoh"
    )
    z = ct.tf([1.0, 0.0], [1.0], DT)
    c = sc.kp * regs.p + sc.kd * regs.d * (1 - 1 / z)
    if regs.i:
        c = c + sc.ki * regs.i * DT / (1 - 1 / z)
    lag = round(ph.loop_delay_s / DT)
    return ct.minreal(c * plant / m.deg_per_tick * (1 / z) ** (1 + lag), verbose=False)


@pytest.mark.parametrize(
    ("family", "regs"),
    [
        ("sts3215", RegisterSet(p=32, i=0, d=32, torque_limit=1000)),
        ("sts3215", RegisterSet(p=120, i=8, d=60, torque_limit=700)),
        ("xl330", RegisterSet(p=400, i=0, d=0, torque_limit=885)),
        ("xl430", RegisterSet(p=640, i=0, d=4000, torque_limit=885)),
    ],
)
def test_margins_match_python_control(family, regs):
    m = load_bus_servo(family)
    got = loop_margins(m, regs)
    worst_ms, worst_gm = 0.0, math.inf
    for k in (0.0, m.jaw.contact_stiffness):
        loop = _ct_loop(m, regs, k)
        gm, _, _, _, _, _ = ct.stability_margins(loop)
        w = np.logspace(-1, math.log10(math.pi / DT) - 1e-6, 4000)
        resp = loop(np.exp(1j * w * DT))
        worst_ms = max(worst_ms, float(np.max(1 / np.abs(1 + resp))))
        worst_gm = min(worst_gm, 20 * math.log10(gm))
        assert ct.feedback(loop, 1).poles().__abs__().max() < 1
    assert got.stable
    assert got.ms == pytest.approx(worst_ms, rel=0.01)
    assert got.gm_db == pytest.approx(worst_gm, abs=0.2)


def test_an_unstable_gain_is_caught():
    m = load_bus_servo("sts3215")
    got = loop_margins(m, RegisterSet(p=254, i=0, d=0, torque_limit=1000))
    loop = _ct_loop(m, RegisterSet(p=254, i=0, d=0, torque_limit=1000))
    assert (np.abs(ct.feedback(loop, 1).poles()).max() > 1) == (not got.stable)


def test_factory_registers_trip_and_the_lerobot_cut_holds():
    """Closing on an object at full torque limit trips the STS3215's overload after its 2 s;
    LeRobot's 50 % torque limit holds (the reason LeRobot cut it)."""
    m = load_bus_servo("sts3215")
    factory, lerobot = judge(m, [m.factory, m.community["lerobot"]])
    assert factory.hold.overload and factory.hold.trip == "overload"
    assert factory.hold.trip_at_s == pytest.approx(m.protection.overload_time_s, abs=0.1)
    assert not lerobot.hold.overload and lerobot.hold.held
    # the held force is the duty limit times stall force, less what the static friction holds
    stall = m.stall_force_n()
    assert lerobot.hold.holding_force_n == pytest.approx(0.5 * stall, abs=m.physics.static * stall)
    # and P = 16 leaves a wider dead band than P = 32
    assert lerobot.tracking.settled_error_deg > factory.tracking.settled_error_deg


def test_hold_metrics_without_object_contact():
    m = load_bus_servo("sts3215")
    from gripper_env.evaluation.bus_servo import hold_goal
    from gripper_env.sim.bus_servo import simulate_bus

    run = simulate_bus(m, m.factory.model_copy(update={"torque_limit": 0}), hold_goal(m),
                       with_object=True, start_deg=m.jaw.open_deg)  # fmt: skip
    h = hold_metrics(m, run)
    assert h.holding_force_n == 0 and math.isnan(h.time_to_grasp_s) and not h.held


def test_the_robust_margins_hold_with_a_tick_more_loop_delay():
    """The delay is identified in whole ticks; the constraints must hold a tick later too, or a
    set tuned on a model one tick short breaks Ms on the servo (found on the README recipe)."""
    model = load_bus_servo("sts3215")
    regs = RegisterSet(p=150, i=0, d=160, torque_limit=790, deadband=1)
    later = model.model_copy(
        update={"physics": model.physics.model_copy(update={"loop_delay_s": 0.005})}
    )
    assert loop_margins(later, regs).ms > loop_margins(model, regs).ms  # a tick more costs margin
    score = judge(model, [regs])[0]
    assert score.robust_margins.ms >= loop_margins(later, regs).ms - 1e-12
    assert score.robust_margins.gm_db <= loop_margins(later, regs).gm_db + 1e-12


def test_in_current_based_position_mode_the_corners_are_in_the_loop_gain():
    """Mode 5: the free loop sees kp and tau_m only through kp w0 / tau_m (no back-EMF term),
    which the records' motion pins, so the corners vary the gains by their 2 sigma (the 10 %
    floor) and keep tau_m as fitted, then a tick more delay; in position control kp and tau_m
    vary apart (four corners)."""
    model = load_bus_servo("xl330").with_updates(operating_mode="current_position")
    corners = corner_models(model)
    assert len(corners) == 4  # the model, two gain corners, a tick more loop delay
    assert sorted(c.scale.kp / model.scale.kp for c in corners[1:3]) == pytest.approx([0.8, 1.2])
    assert sorted(c.scale.kd / model.scale.kd for c in corners[1:3]) == pytest.approx([0.8, 1.2])
    assert {c.physics.tau_m_s for c in corners} == {model.physics.tau_m_s}
    assert corners[3].physics.loop_delay_s == pytest.approx(model.physics.loop_delay_s + DT)
    shipped = load_bus_servo("xl330")
    position = corner_models(shipped)[1:5]
    assert {round(c.scale.kp / shipped.scale.kp, 9) for c in position} == {0.8, 1.2}
    assert {round(c.physics.tau_m_s / shipped.physics.tau_m_s, 9) for c in position} == {0.8, 1.2}


def test_the_robust_margins_hold_on_the_alternative_models():
    """An identification's alternatives (fits at later loop delays, with their own damping and
    time constant) are constraints too: the judged margins are no better than on any of them,
    and a set that breaks Ms on one is infeasible."""
    model = load_bus_servo("sts3215")
    # feasible on the model, its D kick (kd D = 0.296) under the 30 % bound
    regs = RegisterSet(p=75, i=0, d=74, torque_limit=790, deadband=1)
    alt = model.with_updates(
        name="alt",
        physics=model.physics.model_copy(update={"loop_delay_s": 0.006, "tau_m_s": 0.03}),
        scale=model.scale.model_copy(update={"kd": model.scale.kd * 1.3}),
    )
    on_alt = loop_margins(alt, regs)
    plain, with_alt = judge(model, [regs]), judge(model, [regs], alternatives=[alt])
    assert with_alt[0].robust_margins.ms == pytest.approx(
        max(plain[0].robust_margins.ms, on_alt.ms), rel=1e-12
    )
    assert on_alt.ms > 1.6 and not with_alt[0].feasible and plain[0].feasible


def test_a_d_term_that_kicks_more_than_the_bound_is_infeasible():
    """The D term's step for one tick of the reading (kd D, worked by hand: 0.004 x 91 = 0.364
    of full drive on the shipped STS3215) is bounded by D_KICK_MAX, whatever the margins say."""
    model = load_bus_servo("sts3215")
    ok, buzzing = judge(model, [RegisterSet(p=78, i=0, d=75, torque_limit=790),
                                RegisterSet(p=78, i=0, d=91, torque_limit=790)])  # fmt: skip
    assert ok.d_kick == pytest.approx(0.004 * 75) and buzzing.d_kick == pytest.approx(0.364)
    assert buzzing.robust_margins.feasible()  # the margins alone would take it
    assert not buzzing.feasible and buzzing.violations == (
        "D kick 36% of full drive per encoder tick > 30% (a reading flickering between two "
        "ticks buzzes)",
    )
    assert "D kick" not in " ".join(ok.violations)

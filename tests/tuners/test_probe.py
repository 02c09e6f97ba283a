"""Measured margins: the probe agrees with the linear margins of loops whose margins are known."""

import numpy as np
import pytest

from gripper_env.evaluation.stability import stability_report
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from tuners.probe import (
    linear_delay_margin_s,
    measure_margins,
    pid_runner,
    policy_runner,
    probe_disturbance,
    scaled_plant,
)

TEST2 = load_plant("test2")
ACTUAL, IDEAL = load_disturbance("actual"), load_disturbance("ideal")
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")


@pytest.mark.parametrize(
    "plant, gains",
    [("test2", (3.43, 67.5, -0.0087)), ("test4", (0.328, 28.5, 7.7e-6)), ("test2", (4.4, 50, 0))],
)
def test_the_measured_gain_margin_is_the_linear_one(plant, gains):
    g = PIDGains(*gains)
    p = load_plant(plant)
    linear = stability_report(p, g, disturbance=ACTUAL).gain_margin_db
    m = measure_margins(pid_runner(g, OPTIONS), p, ACTUAL, IDEAL)
    assert m.gain_margin_db == pytest.approx(linear, abs=0.3)
    delay = linear_delay_margin_s(p, g, 1, ACTUAL)
    assert m.delay_margin_s == pytest.approx(delay, rel=0.15)
    assert m.nominal_swing_deg < 1e-3


def test_an_oscillating_loop_has_no_margin():
    g = PIDGains(3.43, 67.5, -0.0087)  # tuned on test2; unstable with the hold on test4 x3
    m = measure_margins(
        pid_runner(g, OPTIONS), scaled_plant(load_plant("test4"), 3.0), ACTUAL, IDEAL
    )
    assert m.gain_margin_db == 0.0 and m.nominal_swing_deg > 10.0


def test_a_policy_that_does_nothing_has_its_pids_margins():
    """The residual policy's zero action is the base PID: the probe through the environment's
    compiled step measures the same margins as through the core."""
    base = PIDGains(3.43, 67.5, -0.0087)
    kwargs = {
        "residual": "pid",
        "pid_gains": (base.P, base.I, base.D),
        "residual_deg": 10.0,
        "pid_options": {"output_limits": (0.0, 180.0), "anti_windup": "clamping"},
    }
    zero = policy_runner(lambda obs: np.zeros((len(obs), 1)), kwargs)
    m_policy = measure_margins(zero, TEST2, ACTUAL, IDEAL)
    m_pid = measure_margins(pid_runner(base, OPTIONS), TEST2, ACTUAL, IDEAL)
    assert m_policy.gain_margin_db == pytest.approx(m_pid.gain_margin_db, abs=0.15)


def test_the_probe_loop_is_linear_with_the_hold():
    d = probe_disturbance(ACTUAL, IDEAL)
    assert d.friction.model == "none" and d.command.quantization == "none"
    assert d.command.refresh_period_s == 0.020 and d.sensor.noise_std_deg == 0.0
    assert d.mechanics.limits_deg is None

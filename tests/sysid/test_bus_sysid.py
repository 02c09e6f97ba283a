"""Identification of a bus servo's loop from records at several P settings: a perturbed servo
is recovered, with uncertainties that cover it; records are refused when they cannot work."""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.evaluation.bus_servo import tracking_goal
from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sim.bus_servo import DT, simulate_bus
from gripper_env.sysid.bus_experiments import settings_registers, simulate_record
from gripper_env.sysid.bus_servo import (
    BusRecord,
    identify_bus_servo,
    predict_record,
    read_bus_record,
    write_bus_record,
)


def _records(truth, prior, settings, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for p, d in settings:
        regs = prior.factory.model_copy(update={"p": p, "d": d})
        goal, starts = tracking_goal(prior)
        run = simulate_bus(truth, regs, goal)
        t = np.cumsum(rng.uniform(0.002, 0.004, 2000))
        t = t[t < goal.size * DT - 0.01]
        k = (t / DT).astype(int)
        y = run.position[0][k] * prior.deg_per_tick
        out.append(BusRecord(prior.family, regs, t, goal[k], y, starts * DT, goal[starts]))
    return out


def _fit(y, yhat):
    return 100 * (1 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean()))


@pytest.fixture(scope="module")
def perturbed_sts3215(tmp_path_factory):
    """The recording plan (steps and the creep, five settings) on a perturbed servo, read back
    the way a host reads it (every 2-4 ms, each reading up to 0.5 ms older than its stamp: a
    model error the fit does not know about), through the record file format, and its fit."""
    prior = load_bus_servo("sts3215")
    sc, ph = prior.scale, prior.physics
    truth = prior.with_updates(
        scale=sc.model_copy(update={"kp": sc.kp * 1.2, "kd": sc.kd * 0.8, "ki": sc.ki * 1.3}),
        physics=ph.model_copy(
            update={
                "coulomb": ph.coulomb * 1.2,
                "static": ph.static * 1.22,
                "tau_m_s": ph.tau_m_s * 1.15,
                "omega0_deg_s": ph.omega0_deg_s * 0.9,
                "delay_s": 0.003,
                "loop_delay_s": 0.005,
            }
        ),
    )
    rng = np.random.default_rng(1)
    records = [simulate_record(truth, r, rng=rng) for r in settings_registers(prior)]
    tmp_path = tmp_path_factory.mktemp("records")
    paths = [write_bus_record(tmp_path / f"r{k}.csv", r) for k, r in enumerate(records)]
    records = [read_bus_record(p) for p in paths]
    want = {"kp": truth.scale.kp, "kd": truth.scale.kd, "ki": truth.scale.ki}
    want |= {k: getattr(truth.physics, k) for k in ("tau_m_s", "omega0_deg_s", "coulomb", "static")}
    return records, want, identify_bus_servo(records, prior)


def test_a_perturbed_sts3215_is_recovered(perturbed_sts3215):
    """The loop delay to the tick, the goal's delay within a tick, the gains and the motor
    within 8 %, the friction within 15 % (with 1 deg of backlash the creep pins the static
    friction less sharply: 2.4 % high in one fit, 9.6 % low in another whose records differed
    only by the file's rounding)."""
    records, want, est = perturbed_sts3215
    assert est.fit_pct > 97
    assert est.delay_s == pytest.approx(0.003, abs=DT + 1e-4)
    assert est.loop_delay_s == pytest.approx(0.005, abs=1e-4)
    for k, v in want.items():
        rel = 0.15 if k in ("coulomb", "static") else 0.08
        assert est.values[k] == pytest.approx(v, rel=rel), k
    # I and D were recorded: nothing left at the prior (the notes say only what the delay
    # profile found)
    assert all(n.startswith("loop delay") for n in est.notes), est.notes
    # the alternatives are fits at later loop delays, each nearly as good as the estimate
    for alt in est.alternatives:
        assert est.loop_delay_s < alt.physics.loop_delay_s <= est.loop_delay_s + 2 * DT + 1e-9
        fits = [_fit(r.position_deg, predict_record(alt, r)) for r in records]
        assert min(fits) > 90, fits
    assert est.as_dict()["alternatives"] == [m.model_dump() for m in est.alternatives]


@pytest.mark.xfail(
    strict=True,
    reason="issue 33 (open): since the virtual servo has 1 deg of backlash and the 7.4 V speed, "
    "the fit's stated standard errors understate its error (kp 3.3 % off against a 0.15 % "
    "standard error, 22 of them; 4.7 in another run); the rewrite with autocorrelation-robust "
    "errors is on the wt-bus-int branch, not yet merged",
)
def test_the_stated_standard_errors_cover_the_truth(perturbed_sts3215):
    _records, want, est = perturbed_sts3215
    for k, v in want.items():
        assert abs(est.values[k] - v) <= 3.5 * est.std[k], (k, est.values[k], v, est.std[k])


def test_one_p_setting_is_refused():
    prior = load_bus_servo("sts3215")
    records = _records(prior, prior, [(32, 32), (32, 0)])
    with pytest.raises(ValueError, match="two or more P settings"):
        identify_bus_servo(records, prior)


def test_a_malformed_record_names_its_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("# family=sts3215 p=32 i=0 d=32 torque_limit=1000\nt_s,goal_deg,position_deg\n"
                   "0.0,240,240\n0.1,x,240\n")  # fmt: skip
    with pytest.raises(ValueError, match="line 4"):
        read_bus_record(bad)
    bad.write_text("t_s,goal\n")
    with pytest.raises(ValueError, match="line 1"):
        read_bus_record(bad)

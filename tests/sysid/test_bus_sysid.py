"""Identification of a bus servo's loop from records at several P settings: a perturbed servo
is recovered, with uncertainties that cover it; records are refused when they cannot work."""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.evaluation.bus_servo import tracking_goal
from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sim.bus_servo import DT, simulate_bus
from gripper_env.sysid.bus_servo import (
    BusRecord,
    identify_bus_servo,
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


def test_a_perturbed_sts3215_is_recovered(tmp_path):
    prior = load_bus_servo("sts3215")
    truth = prior.with_updates(
        scale=prior.scale.model_copy(update={"kp": 3.1e-4, "kd": 3.2e-3}),
        physics=prior.physics.model_copy(
            update={
                "coulomb": 0.06,
                "static": 0.11,
                "tau_m_s": 0.035,
                "delay_s": 0.003,
                "loop_delay_s": 0.005,
            }
        ),
    )
    records = _records(truth, prior, [(16, 32), (32, 32), (64, 32), (32, 0)])
    # the records go through their file format
    paths = [write_bus_record(tmp_path / f"r{k}.csv", r) for k, r in enumerate(records)]
    records = [read_bus_record(p) for p in paths]
    est = identify_bus_servo(records, prior)
    assert est.fit_pct > 97
    # delays to a tick: the host reads every 2-4 ms
    assert est.delay_s == pytest.approx(0.003, abs=1.1e-3)
    assert est.loop_delay_s == pytest.approx(0.005, abs=1.1e-3)
    want = {"kp": 3.1e-4, "kd": 3.2e-3, "tau_m_s": 0.035, "coulomb": 0.06, "omega0_deg_s": 270.0}
    for k, v in want.items():
        assert est.values[k] == pytest.approx(v, rel=0.1), k
    # the 95 % range of static friction (pinned only by where steps stop) holds the truth
    lo, hi = est.as_dict()["ranges_95"]["static"]
    assert lo - 0.01 <= 0.11 <= hi + 0.01
    assert "ki" in " ".join(est.notes)  # no record had I > 0: said, not silently kept


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

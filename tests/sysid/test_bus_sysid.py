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
    within 8 %, Coulomb friction within 15 % and the static within 20 % (with 1 deg of backlash
    the creep pins the static friction less sharply: 2.4 % high in one fit, 9.6 % and 17 %
    low in others whose records or searches differed; the standard errors cover it, below)."""
    records, want, est = perturbed_sts3215
    assert est.fit_pct > 97
    assert est.delay_s == pytest.approx(0.003, abs=DT + 1e-4)
    assert est.loop_delay_s == pytest.approx(0.005, abs=1e-4)
    for k, v in want.items():
        rel = {"coulomb": 0.15, "static": 0.20}.get(k, 0.08)
        assert est.values[k] == pytest.approx(v, rel=rel), k
    # I and D were recorded: nothing left at the prior (the notes say only what the delay
    # profile found)
    assert all(n.startswith(("loop delay", "delay pairs")) or "delay pair(s) fit within" in n
               for n in est.notes), est.notes  # fmt: skip
    # the alternatives are the fits at every other delay pair the cost cannot rule out, each
    # nearly as good as the estimate
    pairs = {(round(a.physics.delay_s / DT), round(a.physics.loop_delay_s / DT))
             for a in est.alternatives}  # fmt: skip
    assert len(pairs) == len(est.alternatives)
    assert (round(est.delay_s / DT), round(est.loop_delay_s / DT)) not in pairs
    for alt in est.alternatives:
        fits = [_fit(r.position_deg, predict_record(alt, r)) for r in records]
        assert min(fits) > 90, fits
    assert est.as_dict()["alternatives"] == [m.model_dump() for m in est.alternatives]


def test_the_stated_standard_errors_cover_the_truth(perturbed_sts3215):
    """Every parameter within 3.5 of its stated standard errors of the truth: the records share
    an error the fit does not model (each reading up to 0.5 ms older than its stamp) and the
    backlash gives the cost steps; the standard errors hold the jackknife's refits and the
    spread of the fits at the delay pairs the cost cannot tell apart (five here: the truth's
    pair is the estimate's, every parameter within 2.9 standard errors, static friction 17 %
    low at 7.2 % stated). Before the searches were cut to converge and stop (issue 43) the fit
    found one pair alone and stated 0.1-0.3 % where omega0 was 6.3 errors off."""
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


def test_a_record_round_trips_its_round_trips_and_counts(tmp_path):
    prior = load_bus_servo("sts3215")
    rec = simulate_record(prior, prior.factory)
    rtt = np.linspace(0.001, 0.004, rec.t_s.size)
    rec = BusRecord(rec.family, rec.registers, rec.t_s, rec.goal_deg, rec.position_deg,
                    rec.goal_times_s, rec.goal_values_deg, rtt_s=rtt,
                    goal_rtt_s=np.full(rec.goal_times_s.size, 0.002),
                    stats={"readings": 100, "lost": 12, "slow": 3})  # fmt: skip
    back = read_bus_record(write_bus_record(tmp_path / "r.csv", rec))
    assert np.allclose(back.rtt_s, rtt, atol=1e-6)
    assert np.allclose(back.goal_rtt_s, 0.002)
    assert back.stats == {"readings": 100, "lost": 12, "slow": 3}
    assert back.dropped_fraction == pytest.approx(12 / 112)


def test_an_older_record_without_round_trips_still_reads(tmp_path):
    """Files written before round trips were kept: four columns, goals without one."""
    old = tmp_path / "old.csv"
    old.write_text("# family=sts3215 p=32 i=0 d=32 torque_limit=1000\n"
                   "t_s,goal_deg,position_deg,goal_written\n"
                   + "".join(f"{0.002 * k:.6f},240,240,0\n" for k in range(20))
                   + "# goals\n# 0.000000,240.0000\n")  # fmt: skip
    rec = read_bus_record(old)
    assert np.all(rec.rtt_s == 0) and rec.goal_rtt_s.tolist() == [0.0] and rec.stats == {}


def test_clipped_steps_and_lost_readings_make_a_record_unfit():
    """``check_record``: the steps of the plan on a jaw whose closed stop lies 15 deg below open
    (the 30 deg step stops at the stop), and a record that lost 12 % of its readings; the
    shipped servo's records at every setting pass (their dead band is no clip)."""
    from gripper_env.sysid.bus_experiments import check_record

    prior = load_bus_servo("sts3215")
    for regs in settings_registers(prior):
        assert check_record(simulate_record(prior, regs)) == [], regs.label()
    hi = prior.jaw.limits_deg[1]
    narrow = prior.with_updates(jaw=prior.jaw.model_copy(
        update={"limits_deg": (prior.jaw.open_deg - 15.0, hi)}))  # fmt: skip
    problems = check_record(simulate_record(narrow, prior.factory), "r.csv")
    assert len(problems) == 1 and "r.csv: the step to 210.0 deg" in problems[0], problems
    assert "clipped" in problems[0]
    rec = simulate_record(prior, prior.factory)
    lossy = BusRecord(rec.family, rec.registers, rec.t_s, rec.goal_deg, rec.position_deg,
                      rec.goal_times_s, rec.goal_values_deg,
                      stats={"readings": 880, "lost": 120, "slow": 0})  # fmt: skip
    (problem,) = check_record(lossy)
    assert "12 % of the readings got no reply" in problem


def test_a_mode_5_dead_band_is_no_clip_and_a_stop_still_is():
    """In current-based position control (the Koch gripper's mode 5) the jaw at P 200 stops
    anywhere within the loop's dead band, 8 deg on the XL330's model: beyond the 3 deg floor
    it was taken for a clip; judged against the model's dead band it is not, and a closed stop
    15 deg below open still clips the 30 deg step."""
    from gripper_env.sysid.bus_experiments import check_record

    model = load_bus_servo("xl330").with_updates(operating_mode="current_position")
    low_p = settings_registers(model)[0]
    assert (low_p.p, low_p.d, low_p.goal_current) == (200, 1500, 1470)
    rec = simulate_record(model, low_p)
    assert check_record(rec) != []  # ends 4.6 deg from a goal: more than the 3 deg floor
    assert check_record(rec, model=model) == []
    hi = model.jaw.limits_deg[1]
    narrow = model.with_updates(jaw=model.jaw.model_copy(
        update={"limits_deg": (model.jaw.open_deg - 15.0, hi)}))  # fmt: skip
    (problem,) = check_record(simulate_record(narrow, low_p), "r.csv", model=model)
    assert "r.csv: the step to 210.0 deg" in problem and "clipped" in problem


def test_the_95_percent_ranges_stay_positive(perturbed_sts3215):
    """The ranges are on the logarithm's scale: positive even for a parameter the records pin
    loosely, and equal to ``value * exp(+-1.96 std / value)``."""
    _records, _want, est = perturbed_sts3215
    for k, (lo, hi) in est.ranges_95().items():
        rel = est.std[k] / est.values[k]
        assert 0 < lo < est.values[k] < hi, k
        assert lo == pytest.approx(est.values[k] * np.exp(-1.96 * rel))
        assert hi == pytest.approx(est.values[k] * np.exp(1.96 * rel))

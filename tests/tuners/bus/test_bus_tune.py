"""Tuning a bus servo's integer registers: the result is feasible on the loop as the firmware
runs it, and beats the registers the communities ship on tracking and on the hold."""

from __future__ import annotations

import json

import pytest

from gripper_env.evaluation.bus_servo import GM_MIN_DB, MS_MAX, judge, loop_margins
from gripper_env.model.bus_servo import load_bus_servo, load_registers_file
from tuners.bus.tune import SEARCH_SPACE, main, tune_registers


def test_the_command_writes_a_registers_file(tmp_path, capsys):
    assert main(["--model", "xl330", "--trials", "30", "--polish", "30", "--out", str(tmp_path),
                 "--no-progress", "--no-plot"]) == 0  # fmt: skip
    model, _regs, doc = load_registers_file(tmp_path / "xl330_registers.json")
    assert model.family == "xl330" and doc["score"]["feasible"]
    assert "factory" in doc["baselines"] and "| tuned:" in capsys.readouterr().out
    assert json.loads((tmp_path / "xl330_registers.json").read_text())["trials"] == 30


def test_bad_arguments_are_one_line_errors(capsys):
    assert main(["--model", "nope", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "unknown bus_servo 'nope'" in err and "sts3215" in err
    assert main(["--trials", "0"]) == 2
    assert main(["--polish", "-1"]) == 2
    assert "--polish must be 0..100000, got -1" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_the_search_beats_the_shipped_registers_from_any_seed(family):
    """The tuned registers beat the factory and community sets on the cost, on tracking and on
    the dead band, hold where they trip, meet the margins recomputed on the model, and land in
    the same place from any seed. (TPE alone ended in a hunting high-integrator basin for some
    seeds, at about twice the cost; the log-scale registers and the local search fixed that.)"""
    model = load_bus_servo(family)
    runs = [tune_registers(model, trials=150, seed=s, progress=False) for s in (0, 1, 2)]
    results = [best for best, _study in runs]
    assert all(study.user_attrs["local_optimum"] for _best, study in runs)
    costs = [r.cost for r in results]
    assert max(costs) - min(costs) < 0.05 * min(costs), costs
    shipped = dict(zip(model.baselines(), judge(model, list(model.baselines().values())),
                       strict=True))  # fmt: skip
    for best in results:
        regs = best.registers
        assert all(isinstance(getattr(regs, k), int) for k in SEARCH_SPACE[family])
        assert regs.i <= 0.01 * SEARCH_SPACE[family]["i"][1]  # the integrator only hunts here
        m = loop_margins(model, regs)
        assert m.stable and m.ms <= MS_MAX and m.gm_db >= GM_MIN_DB
        assert best.feasible and best.hold.held and not best.hold.overload
        for name, base in shipped.items():
            assert best.cost < base.cost, name
            assert best.tracking.iae_per_deg_s < base.tracking.iae_per_deg_s, name
            assert best.tracking.settled_error_deg <= base.tracking.settled_error_deg + 1e-9
            # the hold: no trip where the shipped registers trip, and at least the force of
            # any shipped set that holds
            if base.hold.held:
                assert best.hold.min_force_n >= base.hold.min_force_n * 0.9, name
            else:
                assert base.hold.overload or base.hold.min_force_n < base.hold.required_force_n
        # a local optimum on the integer grid: no single-register step of 1 is a feasible set
        # better by more than the search's sufficient decrease
        near = [
            regs.model_copy(update={k: v})
            for k, (lo, hi) in SEARCH_SPACE[family].items()
            for v in (getattr(regs, k) - 1, getattr(regs, k) + 1)
            if lo <= v <= hi
        ]
        assert not [n for n in judge(model, near) if n.feasible and n.cost < best.cost * (1 - 1e-3)]


@pytest.mark.slow
def test_the_koch_gripper_tunes_in_current_based_position_mode(tmp_path, capsys):
    """The XL330 in mode 5 (the Koch gripper's): P, I, D and the goal current are tuned; the
    result meets the margins of the current loop's plant (no back-EMF damping) and holds; a
    given goal current is kept; a family without the mode is a one-line error."""
    args = ["--model", "xl330", "--operating-mode", "current_position", "--trials", "200",
            "--polish", "200", "--out", str(tmp_path), "--no-progress", "--no-plot"]  # fmt: skip
    assert main(args) == 0
    model, regs, doc = load_registers_file(tmp_path / "xl330_registers.json")
    assert model.operating_mode == "current_position" and doc["score"]["feasible"]
    assert "goal_current" in doc["search_space"] and "torque_limit" not in doc["search_space"]
    assert regs.goal_current > 0 and regs.torque_limit == model.factory.torque_limit
    margins = loop_margins(model, regs)
    assert margins.ms <= MS_MAX and margins.gm_db >= GM_MIN_DB
    assert loop_margins(model.with_updates(operating_mode="position"), regs).ms != margins.ms
    best, _ = tune_registers(model, trials=60, polish=60, progress=False, goal_current=600)
    assert best.registers.goal_current == 600
    capsys.readouterr()
    assert main(["--model", "sts3215", "--operating-mode", "current_position"]) == 2
    assert "--operating-mode current_position" in capsys.readouterr().err
    assert main(["--model", "xl330", "--goal-current", "600"]) == 2
    assert "current-based position mode" in capsys.readouterr().err


def test_a_narrow_feasible_region_is_reached_from_the_least_violation():
    """A Koch gripper's fit in mode 5 with the loop delay at 3 ms (its margins judged at 4 ms
    too, where a current-driven loop holds Ms 1.6 only at low gains, and the hold needs force):
    the global stage lands no feasible set, the walk from the least violation reaches one."""
    shipped = load_bus_servo("xl330")
    ph, sc = shipped.physics, shipped.scale
    model = shipped.with_updates(
        operating_mode="current_position",
        scale=sc.model_copy(update={"kp": 8.993e-06, "kd": 5.252e-05}),
        physics=ph.model_copy(update={"tau_m_s": 0.01795, "omega0_deg_s": 583.5,
                                      "coulomb": 0.0274, "static": 0.0274, "delay_s": 0.0,
                                      "loop_delay_s": 0.003}),
    )  # fmt: skip
    best, study = tune_registers(model, trials=60, polish=150, progress=False)
    assert not [t for t in study.trials[:60] if t.user_attrs["constraint"] <= 0.0]
    assert best.feasible and best.robust_margins.ms <= MS_MAX
    assert judge(model, [best.registers])[0].feasible  # judged again, alone


def test_a_mode_5_fit_with_a_late_loop_delay_says_to_record_again():
    """At a 6 ms loop delay (a loaded host's records put it there; the truth's is 3) no set
    holds a current-driven loop's margins and the hold: the error names the delays the margins
    were asked to hold at and says to record again."""
    shipped = load_bus_servo("xl330")
    model = shipped.with_updates(operating_mode="current_position",
                                 physics=shipped.physics.model_copy(
                                     update={"loop_delay_s": 0.006}))  # fmt: skip
    with pytest.raises(RuntimeError, match=r"loop delays up to 7 ms.*record again"):
        tune_registers(model, trials=40, polish=60, progress=False)

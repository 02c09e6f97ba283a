"""Tuning a bus servo's integer registers: the result is feasible on the loop as the firmware
runs it, and beats the registers the communities ship on tracking and on the hold."""

from __future__ import annotations

import json

import pytest

from gripper_env.evaluation.bus_servo import GM_MIN_DB, MS_MAX, judge, loop_margins
from gripper_env.model.bus_servo import load_bus_servo, load_registers_file
from tuners.bus.tune import SEARCH_SPACE, main, tune_registers


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_tuned_registers_beat_the_shipped_ones(family):
    model = load_bus_servo(family)
    best, _study = tune_registers(model, trials=60, seed=1, progress=False)
    regs = best.registers
    assert all(isinstance(getattr(regs, k), int) for k in SEARCH_SPACE[family])
    # margins recomputed on the model and checked against the constraints
    m = loop_margins(model, regs)
    assert m.stable and m.ms <= MS_MAX and m.gm_db >= GM_MIN_DB
    assert best.feasible and best.hold.held and not best.hold.overload
    shipped = judge(model, list(model.baselines().values()))
    for name, base in zip(model.baselines(), shipped, strict=True):
        assert best.cost < base.cost, name
        assert best.tracking.iae_per_deg_s < base.tracking.iae_per_deg_s, name
        assert best.tracking.settled_error_deg <= base.tracking.settled_error_deg + 1e-9, name
        # the hold: no trip where the shipped registers trip, and at least the force of any
        # shipped set that holds
        if base.hold.held:
            assert best.hold.min_force_n >= base.hold.min_force_n * 0.9, name
        else:
            assert base.hold.overload or base.hold.min_force_n < base.hold.required_force_n


def test_the_command_writes_a_registers_file(tmp_path, capsys):
    assert main(["--model", "xl330", "--trials", "30", "--out", str(tmp_path), "--no-progress",
                 "--no-plot"]) == 0  # fmt: skip
    model, _regs, doc = load_registers_file(tmp_path / "xl330_registers.json")
    assert model.family == "xl330" and doc["score"]["feasible"]
    assert "factory" in doc["baselines"] and "| tuned:" in capsys.readouterr().out
    assert json.loads((tmp_path / "xl330_registers.json").read_text())["trials"] == 30


def test_bad_arguments_are_one_line_errors(capsys):
    assert main(["--model", "nope", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "unknown bus_servo 'nope'" in err and "sts3215" in err
    assert main(["--trials", "0"]) == 2

"""``python -m tuners.bus.identify`` refuses what it cannot identify from, with exit status 1 and
one line per problem (clipped steps, lost readings, a fit under 90 %), and ``--force`` takes
them anyway; a refused fit writes no model file."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sysid import bus_servo
from gripper_env.sysid.bus_experiments import settings_registers, simulate_record
from gripper_env.sysid.bus_servo import write_bus_record
from tuners.bus import identify


def _records(tmp_path, model, **stats):
    out = []
    for k, regs in enumerate(settings_registers(model)[:2]):
        rec = simulate_record(model, regs)
        if stats:
            rec = replace(rec, stats=dict(stats))
        out.append(str(write_bus_record(tmp_path / f"record_{k}.csv", rec)))
    return out


def test_clipped_steps_are_refused_before_the_fit(tmp_path, capsys, monkeypatch):
    """The jaw's closed stop 15 deg below open: the 30 deg step of every record is clipped."""
    prior = load_bus_servo("sts3215")
    narrow = prior.with_updates(jaw=prior.jaw.model_copy(
        update={"limits_deg": (prior.jaw.open_deg - 15.0, prior.jaw.limits_deg[1])}))  # fmt: skip
    paths = _records(tmp_path, narrow)

    def never(*_a, **_k):
        raise AssertionError("the fit ran on refused records")

    monkeypatch.setattr(bus_servo, "identify_bus_servo", never)
    assert identify.main([*paths, "--no-plot"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("python -m tuners.bus.identify: error:")
                                 for line in err)  # fmt: skip
    assert "record_0.csv: the step to 210.0 deg" in err[0] and "clipped" in err[0]
    assert "--force" in err[-1]
    assert not list(tmp_path.glob("*_model.json"))


def test_lost_readings_are_refused_and_force_takes_them(tmp_path, capsys, monkeypatch):
    prior = load_bus_servo("sts3215")
    paths = _records(tmp_path, prior, readings=850, lost=150, slow=0)
    seen = {}

    def fake(records, model, **kwargs):  # the fit itself is tested in tests/sysid
        seen["records"] = len(records)
        est = bus_servo.BusEstimate(model, {k: 1.0 for k in bus_servo.FIT_NAMES},
                                    {k: 0.1 for k in bus_servo.FIT_NAMES}, 0.003, 0.004, 97.0,
                                    0.1, [97.0, 96.0])  # fmt: skip
        return est

    monkeypatch.setattr(bus_servo, "identify_bus_servo", fake)
    assert identify.main([*paths, "--no-plot"]) == 1
    err = capsys.readouterr().err
    assert "15 % of the readings got no reply" in err and "seen" not in seen
    assert identify.main([*paths, "--no-plot", "--force", "--quiet"]) == 0
    assert seen["records"] == 2 and (tmp_path / "identified_model.json").is_file()
    assert "warning (--force)" in capsys.readouterr().err


def test_a_fit_under_90_percent_writes_no_model(tmp_path, capsys, monkeypatch):
    prior = load_bus_servo("sts3215")
    paths = _records(tmp_path, prior)

    def poor(records, model, **kwargs):
        values = {k: 1.0 for k in bus_servo.FIT_NAMES}
        return bus_servo.BusEstimate(model, values, values, 0.003, 0.004, 91.0, 0.5,
                                     [97.0, float(np.float64(84.5))])  # fmt: skip

    monkeypatch.setattr(bus_servo, "identify_bus_servo", poor)
    assert identify.main([*paths, "--no-plot", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "record_1.csv fits only 84.5 % (under 90 %)" in err
    assert "the model is not written" in err
    assert not (tmp_path / "identified_model.json").exists()
    assert identify.main([*paths, "--no-plot", "--quiet", "--force"]) == 0
    assert (tmp_path / "identified_model.json").is_file()

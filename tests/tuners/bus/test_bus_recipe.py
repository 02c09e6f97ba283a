"""The README's bus-servo recipe end to end against virtual servos: record -> identify -> tune ->
deploy, for an STS3215 and an XL330, through the commands' own entry points and the vendors' SDKs
(the commands talk to the servo through ``BusLink``).

What the recipe must deliver is in ``bus_recipe``; the STS3215's run is the one on ID 6 of an
arm's bus (``test_bus_shared_bus``), so one end-to-end run serves both.
"""

from __future__ import annotations

import json

import pytest
from bus_recipe import SETTINGS, check_deployed, check_identified, check_tuned, perturbed_truth

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import load_bus_servo
from tuners.bus import calibrate, deploy, identify, record, tune

#: The virtual servo's jaw as its owner would calibrate it: its stops at 150 and 260 deg.
JAW = ["--closed-ticks", "1707", "--open-ticks", "2958"]


@pytest.mark.slow
def test_record_identify_tune_deploy_xl330(tmp_path):
    """The recipe on a lone XL330 at ID 1 (the STS3215's runs on ID 6 of an arm's bus:
    ``test_bus_shared_bus``, with the same checks)."""
    family = "xl330"
    truth = perturbed_truth(family)
    out = tmp_path / family
    jaw = str(tmp_path / "jaw.json")
    with VirtualBus(family, physics=ServoUnit(truth, object_deg=truth.jaw.object_deg)) as bus:
        port = bus.path
        assert calibrate.main(["--port", port, "--id", "1", "--model", family, *JAW,
                               "--out", jaw]) == 0  # fmt: skip
        assert record.main(["--port", port, "--id", "1", "--model", family, "--jaw", jaw,
                            "--out", str(out), "--settings", *SETTINGS[family]]) == 0  # fmt: skip
        records = sorted(out.glob("record_*.csv"))
        assert len(records) == 3
        assert identify.main([*map(str, records), "--model", family, "--name", f"my-{family}",
                              "--generations", "20", "--no-plot"]) == 0  # fmt: skip
        model_file = out / f"my-{family}_model.json"
        check_identified(model_file, truth)
        assert tune.main(["--model", str(model_file), "--trials", "100", "--out", str(out),
                          "--no-plot", "--no-progress"]) == 0  # fmt: skip
        tuned = json.loads((out / f"my-{family}_registers.json").read_text())
        check_tuned(tuned, model_file, truth)
        assert deploy.main(["--registers", str(out / f"my-{family}_registers.json"),
                            "--port", port, "--id", "1", "--hold", "2", "--no-plot",
                            "--save"]) == 0  # fmt: skip
        # what the servo holds now is what was tuned (kept with --save)
        table = bus.table(1)
        regs = tuned["registers"]
        assert table.get_role("p_gain") == regs["p"]
        assert table.get_role("d_gain") == regs["d"]
        assert table.get_role("torque_limit") == regs["torque_limit"]
    report = json.loads((out / f"deploy_my-{family}" / "report.json").read_text())
    check_deployed(report, regs, truth.jaw.object_deg)


def test_deploy_refuses_an_unstable_set_before_touching_the_servo(tmp_path, capsys):
    model = load_bus_servo("sts3215")
    bad = model.factory.model_copy(update={"p": 254, "d": 0})
    path = tmp_path / "bad_registers.json"
    cal = JawCalibration(family="sts3215", closed_ticks=1707, open_ticks=2958)
    doc = {"model": model.calibrated(cal).model_dump(), "registers": bad.model_dump()}
    path.write_text(json.dumps(doc))
    with VirtualBus("sts3215", physics=ServoUnit(model)) as bus:
        before = bus.packets_received
        code = deploy.main(["--registers", str(path), "--port", bus.path, "--id", "1"])
        assert code == 2
        assert bus.packets_received == before  # nothing was sent
        assert bus.table(1).get_role("p_gain") == model.factory.p
    err = capsys.readouterr().err
    assert "refusing to deploy P=254" in err and "unstable" in err


def test_record_refuses_an_unstable_setting_before_touching_the_servo(tmp_path, capsys):
    # the settings are judged in the loop the jaw calibration found the servo in: read first
    jaw = tmp_path / "jaw.json"
    cal = JawCalibration(family="sts3215", closed_ticks=1707, open_ticks=2958)
    jaw.write_text(json.dumps({"calibration": cal.model_dump()}))
    with VirtualBus("sts3215") as bus:
        code = record.main(["--port", bus.path, "--settings", "254,0,0", "32,0,32",
                            "--jaw", str(jaw), "--out", str(tmp_path)])  # fmt: skip
        assert code == 2
        assert bus.packets_received == 0
    assert "refusing to record P=254" in capsys.readouterr().err


def test_record_refuses_a_mode_5_servo_without_goal_current(tmp_path, capsys):
    """Current-based position control with Goal_Current 0 holds no torque: record says so in
    one line, exit 2, and writes nothing (the servo's goal current is the owner's)."""
    table = ControlTable("xl330", 1)
    table.store("operating_mode", 5)
    table.set("goal_current", 0)
    jaw = str(tmp_path / "jaw.json")
    with VirtualBus("xl330", ids=[table]) as bus:
        assert calibrate.main(["--port", bus.path, "--id", "1", "--model", "xl330", *JAW,
                               "--out", jaw]) == 0  # fmt: skip
        before = bytes(table.memory)
        code = record.main(["--port", bus.path, "--id", "1", "--model", "xl330", "--jaw", jaw,
                            "--out", str(tmp_path)])  # fmt: skip
        assert code == 2 and bytes(table.memory) == before
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "goal current 0 (Current_Limit 1750): it holds no torque" in line, line

"""The README's recipe end to end, through the command lines, against the virtual device:
calibrate -> record -> identify (transfer function, friction, sensor, delay) -> tune -> deploy.

Each step is the command a user types (``main(argv)`` of its module, in-process for speed), so
the test keeps working while the commands' insides change. Budgets are small (a 20 s slope,
16 Optuna trials). The identified plant and preset go where the README puts them
(``configs/plants/mine.yaml``, ``configs/disturbances/mine.yaml``) in a copy of the
configuration tree, so the tuner and the deploy gate find them by name.
"""

from __future__ import annotations

import json
import shutil

import pytest

import gripper_env.io.config
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from gripper_env.sysid.greybox import FINE_STEP_DEG
from tuners.sysid.__main__ import main as sysid


@pytest.fixture
def configs(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    shutil.copytree(gripper_env.io.config.CONFIG_DIR, folder)
    monkeypatch.setattr(gripper_env.io.config, "CONFIG_DIR", folder)
    return folder


@pytest.mark.slow
def test_record_identify_tune_deploy(configs, tmp_path, capsys):
    from tuners.optuna import command as optuna_tuner
    from tuners.rig import calibrate, deploy, record

    truth = load_disturbance("actual")
    cal, log = tmp_path / "calibration.json", tmp_path / "mine_slope20.csv"
    board = ["--boot-wait", "0"]
    with VirtualDevice("test2", "actual", speed=0, seed=3) as vd:
        assert calibrate.main(["--port", vd.path, *board, "--output", str(cal)]) == 0
        assert record.main(["--port", vd.path, *board, "--calibration", str(cal),
                            "--profile", "slope20", "--output", str(log)]) == 0  # fmt: skip
    capsys.readouterr()
    plant, preset = configs / "plants" / "mine.yaml", configs / "disturbances" / "mine.yaml"
    assert sysid(["greybox", str(log), "--name", "mine", "--json", "--save-plant", str(plant),
                  "--save-disturbance", str(preset)]) == 0  # fmt: skip
    found = json.loads(capsys.readouterr().out)
    # The virtual rig is test2 behind the actual preset (its board reads the sensor 1 ms late).
    # At speed 0 the slope reaches the board as a staircase whose treads depend on how quickly
    # the host is scheduled, so the record (and the estimate) varies from run to run: the
    # estimate must lie within 15 % of the truth (to the estimator's fine grid step) and inside
    # its own consistent range. That the range holds the truth is a frequency, not a property
    # of one record: tests/sysid/test_coverage.py asks it of at least 90 % of 50 records (a
    # fresh-clone CI run here drew a record whose S range was [2.76, 3.0] deg, the truth 2.5).
    for key in ("S_deg", "J_deg"):
        true, (lo, hi) = getattr(truth.friction, key), found["friction"][f"{key[0]}_range_deg"]
        est = found["friction"][key]
        assert lo <= est <= hi and hi > lo, (key, est, lo, hi)
        tol = max(0.15 * true, FINE_STEP_DEG) + 1e-9
        assert est == pytest.approx(true, abs=tol), (key, est, lo, hi)
    assert found["sensor"]["noise_std_deg"] == pytest.approx(truth.sensor.noise_std_deg, rel=0.15)
    assert found["delay_s"] <= 5e-3  # 1 ms, known to a few ms from a slope
    assert load_plant("mine").is_stable and load_disturbance("mine").friction.model == "choudhury"

    results = tmp_path / "results"
    assert optuna_tuner.main(["--plant", "mine", "--disturbance", "mine", "--trials", "16",
                              "--out", str(results), "--no-progress"]) == 0  # fmt: skip
    gains = results / "mine" / "optuna.json"
    assert json.loads(gains.read_text())["plant"] == "mine"

    out = tmp_path / "deploy"
    with VirtualDevice("test2", "actual", speed=0, seed=4) as vd:
        assert deploy.main(["--gains", str(gains), "--port", vd.path, *board, "--calibration",
                            str(cal), "--disturbance", "mine", "--output-dir", str(out),
                            "--no-plot"]) == 0  # fmt: skip
    report = json.loads((out / "report.json").read_text())
    assert report["stability"]["stable"]
    # the board's response is the one the identified model predicted
    assert report["fit_pct"] > 90.0

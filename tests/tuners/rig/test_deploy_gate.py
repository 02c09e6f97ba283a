"""The deploy gate judges the loop as the board runs it: with the servo's 20 ms command hold."""

import json

import pytest

from gripper_env.evaluation.stability import stability_report
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.gains_file import load_gains_file
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import load_plant
from tests.tuners.conftest import REPO, run_cli

TEST2 = load_plant("test2")
ACTUAL = load_disturbance("actual")  # the loop as the board runs it: the 20 ms command hold

# The old Optuna winner scaled by 1.5: 48 dB of gain margin at 1 ms, unstable with the hold.
FRAGILE = (1.5 * 0.3712425, 1.5 * 98.640685, 1.5 * -0.0025673578)


def _gains_file(path, gains):
    path.write_text(
        json.dumps(
            {"format": "gripper-gains", "format_version": 2, "plant": "test2", "tuner": "manual",
             "P": gains[0], "I": gains[1], "D": gains[2], "N": 100.0, "sign": 1,
             "limits": {"output_deg": [0.0, 180.0], "anti_windup": "clamping", "kb": 1.0}}
        )
    )  # fmt: skip
    return str(path)


def test_gains_stable_at_1ms_but_not_with_the_hold_are_refused(tmp_path):
    report = stability_report(TEST2, PIDGains(*FRAGILE), disturbance=ACTUAL)
    assert report.loop_1ms["stable"] and report.loop_1ms["gain_margin_db"] > 40
    assert not report.stable
    out = tmp_path / "out"
    proc = run_cli(
        "tuners.rig.deploy", "--gains", _gains_file(tmp_path / "g.json", FRAGILE),
        "--port", str(tmp_path / "no-such-port"), "--output-dir", str(out),
    )  # fmt: skip
    assert proc.returncode == 2
    assert "unstable closed loop on plant test2 with the servo's 20 ms command hold" in proc.stderr
    assert proc.stderr.count("\n") == 1 and not out.exists()


@pytest.mark.slow
def test_a_plant_tuned_from_a_users_file_is_gated_on_that_plant(tmp_path):
    """Gains evaluated on the user's own plant file carry its transfer function: deploy gates on
    it even after the plant file is gone (before, it looked the name up and failed)."""
    import yaml

    spec = yaml.safe_load((REPO / "configs" / "plants" / "test2.yaml").read_text())
    spec["name"] = "mygripper"
    spec["num"] = [4.0 * c for c in spec["num"]]  # 12 dB more loop gain than test2
    plant_file = tmp_path / "mygripper.yaml"
    plant_file.write_text(yaml.safe_dump(spec))
    robust_on_test2 = (3.43, 67.5, -0.0087)  # Ms 1.52, GM 10.9 dB on test2 with the hold
    assert stability_report(TEST2, PIDGains(*robust_on_test2), disturbance=ACTUAL).stable
    proc = run_cli(
        "tuners.manual", "--plant", str(plant_file), "--out", str(tmp_path / "res"),
        "--gains", ",".join(map(str, robust_on_test2)), "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    gains_json = tmp_path / "res" / "mygripper" / "manual.json"
    loaded = load_gains_file(gains_json)
    assert loaded.plant_model().num == tuple(spec["num"])  # the recorded transfer function
    plant_file.unlink()
    proc = run_cli(
        "tuners.rig.deploy", "--gains", str(gains_json), "--port", str(tmp_path / "no-such-port"),
        "--output-dir", str(tmp_path / "out"),
    )  # fmt: skip
    assert proc.returncode == 2
    assert "unstable closed loop on plant mygripper" in proc.stderr

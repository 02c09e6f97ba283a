"""The hardware command lines against a virtual board started in the test (its pty as --port)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest

from gripper_env.hardware.host.calibration import load_calibration
from gripper_env.hardware.protocol import Mode
from gripper_env.hardware.virtual import VirtualDevice
from tests.hardware.virtual_support import REPO, gains_file, run_cli, short_step_csv
from tuners.rig import calibrate, deploy, record
from tuners.rig.virtual import board_parser as virtual_parser

SPEED = "--boot-wait", "0"


@pytest.fixture(scope="module")
def virtual() -> Iterator[VirtualDevice]:
    # "max", paced by the host (at most 200 ms of device time past its last frame, then up to
    # 1 s of wall time for the next): at 2x, and once in real time, a command's subprocess on a
    # busy 2-core machine left the 500 ms watchdog without a frame (WATCHDOG stops)
    with VirtualDevice("test2", "actual", speed=0, seed=5) as vd:
        yield vd


@pytest.fixture(scope="module")
def calibration_file(virtual, tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("cal") / "calibration.json"
    result = run_cli(
        "tuners.rig.calibrate", "--port", virtual.path, *SPEED, "--output", str(path),
        "--settle", "1.0", "--average", "0.3",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    return str(path)


def test_calibrate_measures_both_ends(virtual, calibration_file) -> None:
    cal = load_calibration(calibration_file)
    lo, hi = virtual.rig.true_calibration
    # The stiction of the actual model leaves the jaw about half a degree short of each end.
    assert abs(cal.adc_at_21_deg - lo) < 4 and abs(cal.adc_at_92_deg - hi) < 4
    assert cal.port == virtual.path and cal.date


def test_record_writes_the_identification_csv(virtual, calibration_file, tmp_path) -> None:
    out = tmp_path / "ramp.csv"
    result = run_cli(
        "tuners.rig.record", "--port", virtual.path, *SPEED, "--calibration", calibration_file,
        "--profile", "ramp3", "--output", str(out),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert out.exists() and not (tmp_path / "ramp.partial.csv").exists()
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data.dtype.names == ("t_s", "desired_deg", "actual_deg")
    assert len(data) >= 7990 and np.all(np.diff(data["t_s"]) > 0)
    assert abs(data["actual_deg"][-1] - 21.0) < 2.0


@pytest.mark.slow
def test_deploy_runs_stable_gains_and_compares_with_the_prediction(
    virtual, calibration_file, tmp_path
) -> None:
    gains = gains_file(tmp_path / "tuned.json", 1.0, 9.0, -0.001)
    result = run_cli(
        "tuners.rig.deploy", "--gains", gains, "--port", virtual.path, *SPEED,
        "--calibration", calibration_file, "--profile", short_step_csv(tmp_path / "step.csv"),
        "--output-dir", str(tmp_path / "out"),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["fit_pct"] > 85.0
    # frames lost are counted, not fatal: on a busy host the reads fall behind the board's
    # telemetry and the firmware skips frames its full line cannot take, as a real board does
    # (59 and 207 of 4020 in two busy runs); the fit above is judged on what arrived
    link = report["link"]
    assert report["measured"]["stable"] and 0 <= link["frames_lost"] <= 0.1 * link["samples"]
    assert (tmp_path / "out" / "response.png").stat().st_size > 1000
    band = report["settling_band"]  # the band the settling time was judged in, and its parts
    assert band["floor_deg"] >= band["adc_step_deg"] + band["friction_band_deg"]
    assert f"within +/-{band['floor_deg']:.2f} deg" in result.stdout
    header = (tmp_path / "out" / "response.csv").read_text().splitlines()[0]
    assert header == "t_s,reference_deg,command_deg,position_deg"


@pytest.mark.slow
def test_deploy_gate_refuses_unstable_gains_and_the_override_runs_them(
    virtual, calibration_file, tmp_path
) -> None:
    gains = gains_file(tmp_path / "hw.json", -0.5, -3.6, 0.000186)  # paper's hardware gains
    args = ("--gains", gains, "--port", virtual.path, *SPEED, "--calibration", calibration_file)
    out = ("--output-dir", str(tmp_path / "out"), "--no-plot")
    refused = run_cli("tuners.rig.deploy", *args, *out)
    assert refused.returncode == 2
    assert "unstable closed loop on plant test2" in refused.stderr
    assert "Traceback" not in refused.stderr and len(refused.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    short = ("--profile", short_step_csv(tmp_path / "step.csv"))
    forced = run_cli("tuners.rig.deploy", *args, *out, *short, "--allow-unstable")
    assert forced.returncode == 0, forced.stderr
    # the jaw clamp held whatever the PID asked
    data = np.genfromtxt(tmp_path / "out" / "response.csv", delimiter=",", names=True)
    assert np.nanmin(data["command_deg"]) >= 21.0 and np.nanmax(data["command_deg"]) <= 92.0


def test_record_runs_again_when_frames_are_lost_and_keeps_the_gapped_log(
    virtual, calibration_file, tmp_path
) -> None:
    out = tmp_path / "ramp.csv"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [sys.executable, "-m", "tuners.rig.record", "--port", virtual.path, *SPEED,
         "--calibration", calibration_file, "--profile", "ramp3", "--output", str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    # lose telemetry once the first run streams its profile (the first open-loop tick)
    deadline = time.monotonic() + 120.0
    while virtual.firmware.mode != Mode.OPEN_LOOP and time.monotonic() < deadline:
        time.sleep(0.002)
    virtual.drop_frames(3)
    stdout, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr
    assert "samples missing from the record" in stderr and "recording again (run 2" in stderr
    gapped = tmp_path / "ramp.attempt1.csv"
    for path, gaps in ((gapped, True), (out, False)):
        t = np.genfromtxt(path, delimiter=",", names=True)["t_s"]
        assert bool(np.any(np.diff(t) > 0.0015)) == gaps, path
    assert "recorded ramp3" in stdout and "ramp.attempt2" not in stderr


def test_bad_input_is_one_line_and_status_2(tmp_path) -> None:
    result = run_cli("tuners.rig.deploy", "--gains", str(tmp_path / "none.json"), "--port", "x")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"python -m tuners.rig.deploy: error: cannot read gains file {tmp_path / 'none.json'}: "
        "No such file or directory"
    ]


@pytest.mark.parametrize(
    "parser",
    [calibrate._parser(), record._parser(), deploy._parser(), virtual_parser()],
    ids=["calibrate", "record", "deploy", "virtual"],
)
def test_help_documents_every_flag(parser: argparse.ArgumentParser) -> None:
    text = parser.format_help()
    for action in parser._actions:
        for option in action.option_strings:
            assert option in text
        assert action.help, action.option_strings

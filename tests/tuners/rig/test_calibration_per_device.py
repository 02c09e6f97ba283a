"""Calibrations per board (issue 45, item 3): ``calibrate`` against a virtual board wrote the one
calibration file every clone shares, and ``record`` and ``deploy`` read it for any board. Now
each board's calibration is its own file, named by its device id; a file given for another
board is refused, naming both; the real board's file is never touched."""

from __future__ import annotations

import json

import pytest

from gripper_env.hardware.host.calibration import (
    UNSET_DEVICE_ID,
    Calibration,
    calibration_path_for,
    device_key,
    save_calibration,
)
from gripper_env.hardware.twin.rig import VIRTUAL_DEVICE_ID
from gripper_env.hardware.virtual import VirtualDevice
from tests.hardware.virtual_support import run_cli, short_step_csv

SPEED = "--boot-wait", "0"
OTHER_ID = 0x12345678


@pytest.fixture
def homes(tmp_path, monkeypatch):
    """The user's folders in the test's: the calibrations folder and the home (the single file
    of earlier versions, ~/.config/gripper_env/calibration.json)."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("GRIPPER_CALIBRATION_DIR", str(tmp_path / "calibrations"))
    monkeypatch.delenv("GRIPPER_CALIBRATION", raising=False)
    return tmp_path


def _one_line(result) -> str:
    lines = [x for x in result.stderr.strip().splitlines() if not x.startswith("recording ")]
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert len(lines) == 1, result.stderr
    return lines[0]


def test_keys_tell_boards_apart():
    assert device_key(VIRTUAL_DEVICE_ID, "/dev/pts/3") == "56495254"
    assert device_key(VIRTUAL_DEVICE_ID, "/dev/pts/4") == "56495254"  # a pty changes per run
    assert device_key(UNSET_DEVICE_ID, "/dev/ttyACM0") == "unset-id-dev-ttyACM0"
    assert device_key(None, "COM3") == "unset-id-COM3"


def test_a_virtual_boards_calibration_never_replaces_a_real_ones(homes, tmp_path):
    # the real rig's calibration: a Mega whose EEPROM id was never written, on /dev/ttyACM0
    real = calibration_path_for(UNSET_DEVICE_ID, "/dev/ttyACM0")
    save_calibration(Calibration.measured(80.2, 348.6, "/dev/ttyACM0",
                                          device_id=UNSET_DEVICE_ID), real)  # fmt: skip
    real_bytes = real.read_bytes()
    with VirtualDevice("test2", "actual", speed=0, seed=5) as board:
        result = run_cli("tuners.rig.calibrate", "--port", board.path, *SPEED,
                         "--settle", "1.0", "--average", "0.3")  # fmt: skip
        assert result.returncode == 0, result.stderr
    assert real.read_bytes() == real_bytes
    virtual = calibration_path_for(VIRTUAL_DEVICE_ID, board.path)
    assert str(virtual) in result.stdout
    assert json.loads(virtual.read_text())["device_id"] == VIRTUAL_DEVICE_ID
    assert not (homes / "home" / ".config" / "gripper_env" / "calibration.json").exists()

    # another board: the virtual board's file is refused, naming both; nothing is recorded
    with VirtualDevice("test2", "actual", speed=0, seed=5, device_id=OTHER_ID) as other:
        out = tmp_path / "mine.csv"
        common = ("--port", other.path, *SPEED, "--profile", short_step_csv(tmp_path / "s.csv"),
                  "--output", str(out))  # fmt: skip
        line = _one_line(run_cli("tuners.rig.record", *common, "--calibration", str(virtual)))
        assert (
            f"--calibration {virtual}: the calibration of device 0x56495254 (the virtual " in line
        )
        assert "not of this board, device 0x12345678 on " + other.path in line
        # without a file: its own, which it does not have yet
        line = _one_line(run_cli("tuners.rig.record", *common))
        assert line.endswith(
            f"no calibration for device 0x12345678 on {other.path} at "
            f"{calibration_path_for(OTHER_ID, other.path)}: run 'python -m tuners.rig.calibrate "
            f"--port {other.path}' first"
        )
        assert not out.exists() and not list(tmp_path.glob("mine*"))
        # calibrate does not overwrite another board's file either, and the jaw stays put
        result = run_cli("tuners.rig.calibrate", "--port", other.path, *SPEED,
                         "--output", str(virtual))  # fmt: skip
        assert "the calibration of device 0x56495254" in _one_line(result)
        assert "not replaced" in result.stderr
    assert json.loads(virtual.read_text())["device_id"] == VIRTUAL_DEVICE_ID
    assert real.read_bytes() == real_bytes

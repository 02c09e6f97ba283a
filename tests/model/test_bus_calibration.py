"""The owner's jaw calibration: the model frame (both senses), the jaw it gives the model, the
checks on load, LeRobot's calibration file read as data, and the calibration carried through a
record file."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from gripper_env.io.config import ConfigError
from gripper_env.model.bus_calibration import (
    DEG_PER_TICK,
    JawCalibration,
    ServoRegisters,
    read_jaw_file,
    read_lerobot_motor,
)
from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sysid.bus_experiments import simulate_record
from gripper_env.sysid.bus_servo import read_bus_record, write_bus_record

SERVO = ServoRegisters(model_number=777, homing_offset=-5, min_position=1750,
                       max_position=2950, operating_mode=0, max_torque_limit=500)  # fmt: skip


@pytest.mark.parametrize(("closed", "opened"), [(1760, 2940), (2940, 1760)])
def test_the_model_frame_closes_towards_smaller_angles(closed, opened):
    cal = JawCalibration(family="sts3215", closed_ticks=closed, open_ticks=opened, servo=SERVO)
    (lo, hi), open_deg, object_deg = cal.jaw_angles()
    assert lo < object_deg < open_deg < hi
    assert (cal.deg(closed), cal.deg(opened)) == (lo, hi)
    for t in (1750, 1760, 2345, 2940):
        assert cal.ticks(cal.deg(t)) == t
    assert cal.goal_range_ticks() == (1760, 2940)
    assert hi - lo == pytest.approx(1180 * DEG_PER_TICK)


def test_a_calibration_at_the_virtual_servos_stops_gives_back_the_shipped_jaw():
    shipped = load_bus_servo("sts3215")
    cal = JawCalibration(family="sts3215", closed_ticks=1707, open_ticks=2958)
    jaw = shipped.calibrated(cal).jaw
    assert np.allclose(jaw.limits_deg, shipped.jaw.limits_deg, atol=0.05)
    assert jaw.open_deg == pytest.approx(shipped.jaw.open_deg, abs=0.05)
    assert jaw.object_deg == pytest.approx(shipped.jaw.object_deg, abs=0.05)
    assert (jaw.contact_stiffness, jaw.finger_lever_m) == (
        shipped.jaw.contact_stiffness, shipped.jaw.finger_lever_m)  # fmt: skip


def test_checks_on_a_calibration_and_a_calibrated_model():
    with pytest.raises(ValueError, match="deg apart; a jaw needs at least 5 deg"):
        JawCalibration(family="xl330", closed_ticks=2000, open_ticks=2040)
    with pytest.raises(ValueError, match="open_ticks 3000 lies outside the servo's position"):
        JawCalibration(family="sts3215", closed_ticks=1760, open_ticks=3000, servo=SERVO)
    no_limits = SERVO.model_copy(update={"min_position": 0, "max_position": 0})  # multi-turn
    cal = JawCalibration(family="sts3215", closed_ticks=1000, open_ticks=3500, servo=no_limits)
    assert cal.goal_range_ticks() == (1000, 3500)
    shipped = load_bus_servo("sts3215")
    with pytest.raises(ValueError, match="of a xl330, the model 'sts3215' of a sts3215"):
        shipped.calibrated(JawCalibration(family="xl330", closed_ticks=1760, open_ticks=2940))
    data = shipped.calibrated(cal).model_dump()
    data["jaw"]["limits_deg"] = [150.0, 260.0]  # edited by hand: not the calibration's
    with pytest.raises(ValueError, match="are not the calibration's"):
        type(shipped).model_validate(data)
    bad = shipped.model_dump()
    bad["scale"]["kp"] = math.inf
    with pytest.raises(ValueError, match="finite"):
        type(shipped).model_validate(bad)


def test_files_name_themselves_and_their_keys(tmp_path):
    path = tmp_path / "jaw.json"
    path.write_text(json.dumps({"calibration": {"family": "sts3215", "closed_ticks": "a"}}))
    with pytest.raises(ConfigError, match=r"jaw.json: key 'closed_ticks'.*key 'open_ticks'"):
        read_jaw_file(path)
    with pytest.raises(ConfigError, match=r"jaw calibration file .* does not exist"):
        read_jaw_file(tmp_path / "none.json")
    arm = tmp_path / "so101.json"
    arm.write_text(json.dumps({"gripper": {"id": 6, "drive_mode": 0, "homing_offset": 12,
                                           "range_min": 2000, "range_max": 3300}}))  # fmt: skip
    motor = read_lerobot_motor(arm, "gripper")
    assert (motor.id, motor.homing_offset, motor.range_min, motor.range_max) == (6, 12, 2000, 3300)
    with pytest.raises(ConfigError, match=r"so101.json: no motor 'wrist'; it has \['gripper'\]"):
        read_lerobot_motor(arm, "wrist")


def test_a_record_carries_its_calibration(tmp_path):
    cal = JawCalibration(family="sts3215", servo_id=6, closed_ticks=1760, open_ticks=2940,
                         source="given", servo=SERVO)  # fmt: skip
    model = load_bus_servo("sts3215").calibrated(cal)
    rec = simulate_record(model, model.factory)
    path = tmp_path / "record.csv"
    write_bus_record(path, rec)
    assert read_bus_record(path).calibration is None
    write_bus_record(path, replace(rec, calibration=cal))
    back = read_bus_record(path)
    assert back.calibration == cal
    np.testing.assert_array_equal(back.t_s, np.round(rec.t_s, 6))
    lines = path.read_text().splitlines()
    lines[1] = lines[1].replace('"closed_ticks":1760', '"closed_ticks":"x"')
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"record.csv: line 2: key 'closed_ticks'"):
        read_bus_record(path)

"""A servo's memory: defaults, the firmware's checks on host writes, REG_WRITE/ACTION, power
cycles and the write bookkeeping the physics reads."""

from __future__ import annotations

import pytest

from gripper_env.hardware.bus import dynamixel as dxl
from gripper_env.hardware.bus.control_table import ControlTable


def le(value: int, size: int) -> bytes:
    return value.to_bytes(size, "little", signed=value < 0)


def test_defaults_id_and_model():
    t = ControlTable("xl330", servo_id=7)
    assert (t.servo_id, t.get("model_number"), t.get("position_p_gain")) == (7, 1200, 400)
    assert t.read(0, 2) == le(1200, 2)
    assert t.get("goal_pwm") == t.get("pwm_limit") == 885
    s = ControlTable("sts3215", servo_id=3)
    assert (s.get("id"), s.get_role("model_number"), s.read(3, 2)) == (3, 777, le(777, 2))
    assert (s.get_role("p_gain"), s.get_role("d_gain"), s.get_role("i_gain")) == (32, 32, 0)
    with pytest.raises(ValueError, match=r"id must be in \[0, 253\]"):
        ControlTable("sts3215", servo_id=254)


def test_reads_past_the_memory():
    t = ControlTable("xl430")
    assert t.check_read(132, 4) == 0
    assert t.check_read(146, 4) == dxl.ERR_ACCESS  # beyond the table
    assert t.read(146, 4)[1:] == bytes(3)  # an STS answers zeros there


def test_dynamixel_write_checks():
    t = ControlTable("xl330")
    assert t.write(116, le(1000, 4)) == 0 and t.get("goal_position") == 1000
    assert t.write(116, le(1000, 2)) == dxl.ERR_DATA_LENGTH  # half of a 4-byte field
    assert t.write(132, le(5, 4)) == dxl.ERR_ACCESS  # present_position is read-only
    assert t.write(66, b"\x00") == dxl.ERR_ACCESS  # a reserved address
    assert t.write(64, b"\x00\x00\x00\x00\x02") == dxl.ERR_ACCESS  # spans reserved bytes
    assert t.write(84, le(16384, 2)) == dxl.ERR_DATA_RANGE  # P gain 0-16383
    assert t.write(100, le(900, 2)) == dxl.ERR_DATA_RANGE  # goal PWM beyond +-885
    assert t.write(36, le(500, 2)) == 0  # PWM limit 500 ...
    assert t.write(100, le(600, 2)) == dxl.ERR_DATA_LIMIT  # ... binds the goal PWM
    assert t.write(100, le(-500, 2)) == 0 and t.get("goal_pwm") == -500
    assert t.write(52, le(1000, 4)) == 0  # min position limit
    assert t.write(116, le(900, 4)) == dxl.ERR_DATA_LIMIT  # below it, in position mode
    assert t.write(11, b"\x04") == 0  # extended position mode: the limits no longer bind
    assert t.write(116, le(900, 4)) == 0
    assert t.get("goal_position") == 900


def test_dynamixel_eeprom_is_locked_while_torque_is_on():
    t = ControlTable("xl430")
    assert t.write(64, b"\x01") == 0
    assert t.write(7, b"\x05") == dxl.ERR_ACCESS
    assert t.write(84, le(800, 2)) == 0  # RAM gains stay writable
    assert t.servo_id == 1
    assert t.write(64, b"\x00") == 0 and t.write(7, b"\x05") == 0
    assert t.servo_id == 5


def test_a_refused_write_writes_nothing():
    t = ControlTable("xl330")
    before = bytes(t.memory)
    # goal PWM (fine) and goal current (beyond the current limit) in one write
    assert t.write(100, le(10, 2) + le(2000, 2)) == dxl.ERR_DATA_RANGE
    assert bytes(t.memory) == before
    assert t.pop_writes() == set()


def test_torque_stays_off_in_alert_until_reboot():
    t = ControlTable("xl330")
    t.set_role("error_status", t.spec.error_bits["overload"])
    assert t.write(64, b"\x01") == dxl.ERR_RESULT_FAIL
    assert t.write(64, b"\x00") == 0  # turning it off is fine
    t.set("present_position", 3000)
    t.reboot()
    assert t.get_role("error_status") == 0
    assert t.get("present_position") == 3000 and t.get("goal_position") == 3000
    assert t.write(64, b"\x01") == 0


def test_pop_writes_reports_what_the_host_wrote():
    t = ControlTable("sts3215")
    assert t.pop_writes() == set()
    t.write(40, b"\x01")
    t.write(41, b"\x05" + le(100, 2))  # acceleration and goal position in one write
    t.set("present_position", 10)  # the servo's own writes do not count
    assert t.pop_writes() == {"torque_enable", "acceleration", "goal_position"}
    assert t.pop_writes() == set()
    t.power_cycle()
    assert t.pop_writes() == {"torque_enable"}


def test_sts_accepts_eeprom_writes_and_saves_them_only_unlocked():
    t = ControlTable("sts3215")
    t.write(40, b"\x01")  # torque on: an STS does not lock its EEPROM
    assert t.write(21, b"\x10") == 0 and t.get("p_coefficient") == 16
    assert t.eeprom_saves == 1  # lock 0: saved
    assert t.write(55, b"\x01") == 0  # lock 1: written, not saved
    assert t.write(21, b"\x08") == 0 and t.get("p_coefficient") == 8
    assert t.eeprom_saves == 1
    t.power_cycle()
    assert t.get("p_coefficient") == 16  # the saved value comes back
    assert (t.get("lock"), t.get("torque_enable")) == (0, 0)
    assert t.get("torque_limit") == t.get("max_torque_limit") == 1000


def test_sts_refuses_out_of_range_values():
    t = ControlTable("sts3215")
    assert t.write(42, le(0x8000 | 31000, 2)) == dxl.ERR_DATA_RANGE  # -31000: beyond +-30719
    assert t.write(42, le(0x8000 | 100, 2)) == 0 and t.get("goal_position") == -100


def test_reg_write_and_action():
    t = ControlTable("xl330")
    assert t.action() is None  # nothing registered
    assert t.reg_write(116, le(123, 4)) == 0
    assert t.get("registered_instruction") == 1 and t.get("goal_position") == 2048
    assert t.action() == 0
    assert t.get("goal_position") == 123 and t.get("registered_instruction") == 0
    assert t.reg_write(116, le(10**7, 4)) == dxl.ERR_DATA_RANGE
    s = ControlTable("sts3215")
    assert s.reg_write(42, le(500, 2)) == 0 and s.get("async_write_flag") == 1
    assert s.action() == 0 and s.get("goal_position") == 500


def test_factory_reset():
    t = ControlTable("xl430", servo_id=4)
    t.write(84, le(100, 2))
    t.write(31, b"\x50")
    t.factory_reset(keep_id=True)
    assert (t.servo_id, t.get("temperature_limit"), t.get("position_p_gain")) == (4, 72, 640)
    t.factory_reset(keep_id=False)
    assert t.servo_id == 1

"""The control tables against their sources: the Dynamixel SDK's table files, LeRobot's STS
table and encodings, the e-manual's factory gains; field encodings and the roles."""

from __future__ import annotations

from importlib.resources import files

import pytest
import scservo_sdk
from hypothesis import given
from hypothesis import strategies as st

from gripper_env.hardware.bus.tables import (
    DEG_PER_TICK,
    ROLES,
    TABLES,
    deg_to_ticks,
    get_spec,
    snake_case,
    ticks_to_deg,
)

# LeRobot, src/lerobot/motors/feetech/tables.py (STS_SMS_SERIES_CONTROL_TABLE), the entries the
# virtual STS3215 holds: name -> (address, size).
LEROBOT_STS = {
    "Firmware_Major_Version": (0, 1),
    "Firmware_Minor_Version": (1, 1),
    "Model_Number": (3, 2),
    "ID": (5, 1),
    "Baud_Rate": (6, 1),
    "Return_Delay_Time": (7, 1),
    "Response_Status_Level": (8, 1),
    "Min_Position_Limit": (9, 2),
    "Max_Position_Limit": (11, 2),
    "Max_Temperature_Limit": (13, 1),
    "Max_Voltage_Limit": (14, 1),
    "Min_Voltage_Limit": (15, 1),
    "Max_Torque_Limit": (16, 2),
    "Phase": (18, 1),
    "Unloading_Condition": (19, 1),
    "LED_Alarm_Condition": (20, 1),
    "P_Coefficient": (21, 1),
    "D_Coefficient": (22, 1),
    "I_Coefficient": (23, 1),
    "Minimum_Startup_Force": (24, 2),
    "CW_Dead_Zone": (26, 1),
    "CCW_Dead_Zone": (27, 1),
    "Protection_Current": (28, 2),
    "Angular_Resolution": (30, 1),
    "Homing_Offset": (31, 2),
    "Operating_Mode": (33, 1),
    "Protective_Torque": (34, 1),
    "Protection_Time": (35, 1),
    "Overload_Torque": (36, 1),
    "Velocity_closed_loop_P_proportional_coefficient": (37, 1),
    "Over_Current_Protection_Time": (38, 1),
    "Velocity_closed_loop_I_integral_coefficient": (39, 1),
    "Torque_Enable": (40, 1),
    "Acceleration": (41, 1),
    "Goal_Position": (42, 2),
    "Goal_Time": (44, 2),
    "Goal_Velocity": (46, 2),
    "Torque_Limit": (48, 2),
    "Lock": (55, 1),
    "Present_Position": (56, 2),
    "Present_Velocity": (58, 2),
    "Present_Load": (60, 2),
    "Present_Voltage": (62, 1),
    "Present_Temperature": (63, 1),
    "Status": (65, 1),
    "Moving": (66, 1),
    "Present_Current": (69, 2),
    # the factory area ("Moving_Velocity" at 80 is another name for the threshold)
    "Moving_Velocity_Threshold": (80, 1),
    "DTs": (81, 1),
    "Velocity_Unit_factor": (82, 1),
    "Hts": (83, 1),
    "Maximum_Velocity_Limit": (84, 1),
    "Maximum_Acceleration": (85, 1),
    "Acceleration_Multiplier ": (86, 1),
}
# LeRobot's STS_SMS_SERIES_ENCODINGS_TABLE (sign bit of each sign-magnitude field)
LEROBOT_STS_SIGN_BITS = {
    "Present_Load": 10,
    "Homing_Offset": 11,
    "Goal_Position": 15,
    "Goal_Velocity": 15,
    "Present_Position": 15,
    "Present_Velocity": 15,
}
# Addresses the brief names (checked independently of the table above)
STS_ADDRESSES = {
    "p_coefficient": 21, "d_coefficient": 22, "i_coefficient": 23, "cw_dead_zone": 26,
    "ccw_dead_zone": 27, "torque_enable": 40, "acceleration": 41, "goal_position": 42,
    "goal_velocity": 46, "torque_limit": 48, "lock": 55, "present_position": 56,
    "present_velocity": 58, "present_load": 60, "present_voltage": 62, "present_temperature": 63,
    "status": 65, "moving": 66, "present_current": 69, "max_torque_limit": 16,
    "protection_current": 28, "protective_torque": 34, "protection_time": 35,
    "overload_torque": 36, "max_temperature_limit": 13, "min_position_limit": 9,
    "max_position_limit": 11,
}  # fmt: skip


def _sdk_model_file(name: str) -> dict[str, tuple[int, int]]:
    """The ``[control table]`` of a dynamixel_easy_sdk ``.model`` file, without the indirect
    address/data entries: snake-case name -> (address, size)."""
    text = (files("dynamixel_easy_sdk") / "control_table" / name).read_text()
    table = text.split("[control table]")[1].strip().splitlines()[1:]
    entries = {}
    for line in table:
        address, size, data_name = line.split("\t")
        if data_name.startswith("Indirect"):
            continue
        entries[snake_case(data_name)] = (int(address), int(size))
    return entries


@pytest.mark.parametrize(("family", "model_file"), [("xl330", "xl330_m288.model"),
                                                     ("xl430", "xl430_w250.model")])  # fmt: skip
def test_the_xl_tables_are_the_sdks_table_files(family, model_file):
    sdk = _sdk_model_file(model_file)
    ours = {f.name: (f.address, f.size) for f in TABLES[family]}
    assert ours == sdk


def test_the_xl_model_numbers_are_the_sdks():
    models = (files("dynamixel_easy_sdk") / "control_table" / "dynamixel.model").read_text()
    by_file = {line.split("\t")[1]: int(line.split("\t")[0]) for line in models.splitlines()[1:]}
    assert TABLES["xl330"].model_number == by_file["xl330_m288.model"] == 1200
    assert TABLES["xl430"].model_number == by_file["xl430_w250.model"] == 1060


def test_the_sts_table_is_lerobots():
    ours = {f.name: (f.address, f.size) for f in TABLES["sts3215"]}
    lerobot = {snake_case(k): v for k, v in LEROBOT_STS.items()}
    # LeRobot's table plus the asynchronous-write flag (64) that REG_WRITE raises
    assert ours == {**lerobot, "async_write_flag": (64, 1)}
    for name, address in STS_ADDRESSES.items():
        assert TABLES["sts3215"].field(name).address == address, name
    assert TABLES["sts3215"].model_number == 777


def test_the_sts_sign_magnitude_fields_are_lerobots():
    spec = TABLES["sts3215"]
    expected = {snake_case(k): f"sign_bit{v}" for k, v in LEROBOT_STS_SIGN_BITS.items()}
    ours = {f.name: f.signed for f in spec if f.signed is not None}
    assert {k: v for k, v in ours.items() if k in expected} == expected
    assert set(ours) - set(expected) == {"goal_time"}  # sign bit 10 in PWM mode (Feetech)


@pytest.mark.parametrize(
    ("family", "gains"),
    [("sts3215", (32, 0, 32)), ("xl330", (400, 0, 0)), ("xl430", (640, 0, 4000))],
)
def test_factory_gains(family, gains):
    spec = TABLES[family]
    assert tuple(spec.role(r).default for r in ("p_gain", "i_gain", "d_gain")) == gains


def test_every_family_has_every_role_it_can():
    common = set(ROLES) - {"deadband_cw", "deadband_ccw", "lock", "present_load",
                           "present_current", "drive_mode", "goal_current"}  # fmt: skip
    for spec in TABLES.values():
        assert common <= set(spec.roles), spec.family
        for role in spec.roles:
            spec.role(role)  # names a field
    assert {"deadband_cw", "deadband_ccw", "lock", "present_load", "present_current"} <= set(
        TABLES["sts3215"].roles
    )
    assert TABLES["xl330"].roles["present_current"] == "present_current"
    assert TABLES["xl330"].roles["goal_current"] == "goal_current"  # current-based position
    assert "goal_current" not in TABLES["xl430"].roles
    assert all(TABLES[f].roles["drive_mode"] == "drive_mode" for f in ("xl330", "xl430"))
    assert "present_load" not in TABLES["xl330"].roles
    assert TABLES["xl430"].roles["present_load"] == "present_load"
    assert "present_current" not in TABLES["xl430"].roles
    for family in ("xl330", "xl430"):
        spec = TABLES[family]
        assert spec.roles["torque_limit"] == "goal_pwm"
        assert spec.role("torque_limit").limits == ("-pwm_limit", "pwm_limit")
        assert spec.role("torque_limit").area == "RAM"
        assert spec.roles["error_status"] == "hardware_error_status"
        assert spec.roles["acceleration"] == "profile_acceleration"
        assert spec.roles["velocity_limit"] == "profile_velocity"
    sts = TABLES["sts3215"]
    assert (sts.role("torque_limit").name, sts.role("torque_limit").hi) == ("torque_limit", 1000)
    assert sts.roles["error_status"] == "status"
    assert sts.roles["velocity_limit"] == "goal_velocity"


def test_positions_are_4096_ticks_per_revolution():
    for spec in TABLES.values():
        assert spec.ticks_per_rev == 4096
        assert spec.deg_to_ticks(90.0) == 1024
        assert spec.ticks_to_deg(2048) == 180.0
    assert DEG_PER_TICK == 0.087890625
    assert deg_to_ticks(0.087890625 * 7) == 7
    assert ticks_to_deg(-1) == -0.087890625


def test_sign_magnitude_matches_the_scservo_sdk():
    f = TABLES["sts3215"].field("goal_position")
    assert f.encode(-5) == bytes([0x05, 0x80])
    assert f.decode(bytes([0x05, 0x80])) == -5
    load = TABLES["sts3215"].field("present_load")
    assert load.encode(-1000) == (0x400 | 1000).to_bytes(2, "little")


@given(st.integers(-30719, 30719))
def test_sign_magnitude_round_trip_agrees_with_scs_toscs(value):
    f = TABLES["sts3215"].field("goal_position")
    raw = int.from_bytes(f.encode(value), "little")
    assert raw == scservo_sdk.SCS_TOSCS(value, 15)
    assert f.decode(f.encode(value)) == value == scservo_sdk.SCS_TOHOST(raw, 15)


@given(st.integers(-(2**31), 2**31 - 1))
def test_twos_complement_round_trip(value):
    f = TABLES["xl330"].field("present_position")
    assert f.encode(value) == value.to_bytes(4, "little", signed=True)
    assert f.decode(f.encode(value)) == value


def test_unencodable_values_are_refused():
    with pytest.raises(ValueError, match="goal_pwm"):
        TABLES["xl330"].field("goal_pwm").encode(40000)
    with pytest.raises(ValueError, match=r"p_coefficient must be in \[0, 254\]"):
        TABLES["sts3215"].field("p_coefficient").check(300)
    with pytest.raises(ValueError, match="read-only"):
        TABLES["sts3215"].field("present_position").check(0)


def test_an_unknown_family_names_the_known_ones():
    with pytest.raises(ValueError, match="sts3215, xl330, xl430"):
        get_spec("xl320")
    with pytest.raises(KeyError, match="role 'p_gain' is 'position_p_gain'"):
        TABLES["xl330"].field("p_gain")
    assert TABLES["xl330"].resolve("p_gain").name == "position_p_gain"

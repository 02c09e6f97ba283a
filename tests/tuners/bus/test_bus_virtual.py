"""``python -m tuners.bus.virtual --lerobot``: the gripper as LeRobot's SO or Koch follower
leaves it, its registers in flash (they survive a power cycle), read by the vendor's SDK."""

from __future__ import annotations

import pytest
from bus_arm import sdk_registers

from gripper_env.hardware.bus.server import VirtualBus
from tuners.bus.virtual import LEROBOT_GRIPPER, _gripper_table


def test_lerobots_gripper_registers_are_in_flash():
    """As a LeRobot session leaves the gripper, and after a power cycle its EEPROM-area
    registers (the gains, the limits, the protection) from flash; the RAM ones come back at
    their power-on values (the torque limit from Max_Torque_Limit)."""
    table = _gripper_table("sts3215", 6, [1750, 2950], lerobot=True)
    spec = table.spec
    with VirtualBus("sts3215", ids=[table]) as bus:
        session = sdk_registers(bus.path, "sts3215", 6)
        bus.power_cycle(6)  # what the servo comes up with: its flash
        powered = sdk_registers(bus.path, "sts3215", 6)
    for name, value in LEROBOT_GRIPPER["sts3215"].items():
        assert int.from_bytes(session[name], "little") == value, name
        if spec.field(name).area == "EEPROM":
            assert int.from_bytes(powered[name], "little") == value, name
    assert int.from_bytes(powered["torque_limit"], "little") == 500
    assert int.from_bytes(powered["max_position_limit"], "little") == 2950


def test_lerobots_koch_gripper_is_in_mode_5_after_a_power_cycle():
    """The Koch follower's XL330 gripper: current-based position mode and Return_Delay_Time 0
    in flash, its Goal_Current at power-on the Current_Limit (koch_follower.configure writes no
    current); the XL430 is no LeRobot gripper."""
    table = _gripper_table("xl330", 6, None, lerobot=True)
    with VirtualBus("xl330", ids=[table]) as bus:
        bus.power_cycle(6)
        assert (table.get("operating_mode"), table.get("return_delay_time")) == (5, 0)
        assert table.get("baud_rate") == table.spec.baud_index(1_000_000)  # LeRobot's rate
        assert table.get("goal_current") == table.get("current_limit") == 1750
    with pytest.raises(ValueError, match="--lerobot: LeRobot's followers have an STS3215"):
        _gripper_table("xl430", 6, None, lerobot=True)

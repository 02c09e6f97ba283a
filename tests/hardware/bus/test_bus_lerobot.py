"""LeRobot's own motor buses against the virtual servos: FeetechMotorsBus on a virtual STS3215
and DynamixelMotorsBus on a virtual XL330, through scan_port, connect, configure_motors, the
calibration round trip (set_half_turn_homings, write_calibration, read_calibration),
sync_write / sync_read of normalised goals and positions, and disconnect.

LeRobot 0.6 needs Python >= 3.12: it runs in its own environment, ``.lerobot-venv``, which
``scripts/lerobot-env.sh`` builds (``.ci/run`` does), as a subprocess driving the bus the test
serves. The truth it is held to is the servo's own state: the homing offset LeRobot wrote, the
shaft's true angle against the goal LeRobot sent through its calibration, the registers its
configure step wrote. Skipped, with the reason, when that environment is absent.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from lerobot_support import LEROBOT_MARKS, LEROBOT_PYTHON, run_lerobot

from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit

pytestmark = LEROBOT_MARKS
SERVO_ID = 6  # the gripper's ID on an SO-101 / Koch bus

# A LeRobot user's session, run by LeRobot's interpreter: argv = port, family, goal (0-100).
CLIENT = r"""
import json, sys, time
from lerobot.motors import Motor, MotorCalibration, MotorNormMode

port, family, goal = sys.argv[1], sys.argv[2], float(sys.argv[3])
# The reply window is the host's choice, not the servo's. LeRobot 0.6 waits 50 ms (Feetech: its
# patch_setPacketTimeout) or the SDK's 34 ms (Dynamixel). The virtual servo is a thread of the
# test's process, which a loaded test machine leaves unscheduled for longer at times
# (tests/conftest.py): this session waits 500 ms for a reply.
import dynamixel_sdk.port_handler
import lerobot.motors.feetech.feetech as feetech_module

def patient_packet_timeout(self, packet_length):
    self.packet_start_time = self.getCurrentTime()
    self.packet_timeout = self.tx_time_per_byte * packet_length + 500.0

dynamixel_sdk.port_handler.LATENCY_TIMER = 249
feetech_module.patch_setPacketTimeout = patient_packet_timeout
if family == "sts3215":
    from lerobot.motors.feetech import FeetechMotorsBus as Bus
    model = "sts3215"
else:
    from lerobot.motors.dynamixel import DynamixelMotorsBus as Bus
    model = "xl330-m288"
out = {"scan": {str(k): v for k, v in Bus.scan_port(port).items()}}
bus = Bus(port, {"gripper": Motor(6, model, MotorNormMode.RANGE_0_100)})
bus.connect()
bus.configure_motors()
bus.disable_torque()
if family == "xl330":
    bus.write("Operating_Mode", "gripper", 5)  # the Koch gripper's current-based position mode
out["before"] = bus.sync_read("Present_Position", normalize=False)["gripper"]
out["homing"] = int(bus.set_half_turn_homings()["gripper"])
out["after"] = bus.sync_read("Present_Position", normalize=False)["gripper"]
lo, hi = out["after"] - 900, out["after"] + 200  # the jaw's range as record_ranges_of_motion saw it
calibration = {"gripper": MotorCalibration(id=6, drive_mode=0, homing_offset=out["homing"],
                                           range_min=lo, range_max=hi)}
bus.write_calibration(calibration)
read = bus.read_calibration()["gripper"]
out["read"] = [read.homing_offset, read.range_min, read.range_max]
out["is_calibrated"] = bool(bus.is_calibrated)
bus.enable_torque()
bus.sync_write("Goal_Position", {"gripper": goal})
time.sleep(1.5)
out["goal_raw"] = bus.read("Goal_Position", "gripper", normalize=False)
out["present"] = bus.sync_read("Present_Position")["gripper"]
out["present_raw"] = bus.sync_read("Present_Position", normalize=False)["gripper"]
bus.disconnect()
print(json.dumps(out))
"""


def _run_client(bus: VirtualBus, family: str, goal: float) -> dict[str, object]:
    return run_lerobot(CLIENT, bus.path, family, str(goal), timeout=240)


@pytest.mark.parametrize(
    ("family", "baudrate"), [("sts3215", None), ("xl330", 1_000_000)], ids=["feetech", "dynamixel"]
)
def test_lerobot_calibration_round_trip_with_the_homing_offset_in_effect(family, baudrate):
    unit = ServoUnit(family)
    with VirtualBus(family, ids=(SERVO_ID,), physics=unit, baudrate=baudrate) as bus:
        out = _run_client(bus, family, goal=50.0)
        table = bus.table(SERVO_ID)
        dpt = unit.model.deg_per_tick
        # the servo answers at one rate only (its Baud_Rate: 1 Mbaud, LeRobot's default)
        assert out["scan"] == {"1000000": [SERVO_ID]}
        # configure_motors: Return_Delay_Time 0 (and on the STS the factory area's
        # Maximum_Acceleration and Acceleration 254)
        assert table.get("return_delay_time") == 0
        if family == "sts3215":
            assert table.get("maximum_acceleration") == 254 and table.get("acceleration") == 254
        # the half-turn homing LeRobot computed is in the servo, and moves the present position
        # to the half turn (STS: present = actual - offset; Dynamixel: actual + offset)
        actual = round(out["before"])
        sign = 1 if family == "sts3215" else -1
        assert out["homing"] == sign * (actual - 2047)
        assert table.get_role("homing_offset") == out["homing"]
        assert out["after"] == 2047
        lo, hi = 2047 - 900, 2047 + 200
        assert out["read"] == [out["homing"], lo, hi] and out["is_calibrated"]
        # the normalised goal 50 % went out in the calibrated frame and the shaft went there:
        # its true angle is the goal shifted by the homing offset
        assert out["goal_raw"] == lo + (hi - lo) // 2
        shaft_goal = out["goal_raw"] + sign * out["homing"]
        band = unit.model.physics.static / (unit.model.scale.kp * 32) + 2  # ticks (P 32 / 400)
        band += unit.model.physics.backlash_deg / dpt
        assert abs(unit.angle_deg / dpt - shaft_goal) <= max(band, 4)
        assert abs(out["present"] - 50.0) < 100 * max(band, 4) / (hi - lo)
        # disconnect turned the torque off
        assert table.get_role("torque_enable") == 0


def test_the_client_runs_in_lerobots_own_interpreter():
    """The environment is LeRobot 0.6 on Python >= 3.12, not this test's interpreter."""
    proc = subprocess.run(
        [str(LEROBOT_PYTHON), "-c", "import sys, importlib.metadata as m; "
         "print(sys.version_info[:2] >= (3, 12), m.version('lerobot'))"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    ok, version = proc.stdout.split()
    assert ok == "True" and version.startswith("0.6") and sys.executable != str(LEROBOT_PYTHON)

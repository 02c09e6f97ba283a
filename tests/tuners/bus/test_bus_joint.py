"""``python -m tuners.bus.joint``: the loaded-joint recipe end to end on the six-servo SO-101
bus with gravity on every joint (record around the held pose, identify the load, tune against
it), 0 packets to the other IDs and every register of the joint restored; refusals before a
byte moves."""

from __future__ import annotations

import json
import time

import pytest
from bus_arm import sdk_registers

from gripper_env.evaluation.bus_load import judge_loaded
from gripper_env.hardware.bus.arm import SO101_IDS, VirtualArm, arm_registers
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.model.so101_arm import joint_model
from tuners.bus import joint

ELBOW = 3


def test_virtual_arm_sags_under_gravity():
    """Every joint on its own servo at LeRobot's P 16: the shoulder and the elbow sag by
    degrees under the arm's weight and 100 g, the shoulder more with the payload; the pan,
    whose axis is vertical, does not."""
    sag = {}
    for payload in (0.0, 0.1):
        arm = VirtualArm(payload_kg=payload)
        with arm.bus() as bus:
            assert sdk_registers(bus.path, "sts3215", ELBOW)  # the servo answers
            time.sleep(1.5)  # the bus advances every servo (and their coupling) on the next
            sdk_registers(bus.path, "sts3215", 1)
            sag[payload] = {j: arm.units[j].angle_deg - 180.0 for j in SO101_IDS.values()}
    assert abs(sag[0.1]["shoulder_lift"]) > abs(sag[0.0]["shoulder_lift"]) + 2.0
    assert abs(sag[0.1]["elbow_flex"]) > 3.0
    assert abs(sag[0.1]["shoulder_pan"]) < 0.2


def test_record_refuses_without_the_neighbours_held(tmp_path, capsys):
    arm = VirtualArm()
    with arm.bus() as bus:
        status = joint.main(["record", "--port", bus.path, "--id", "3", "--joint",
                             "elbow_flex", "--out", str(tmp_path / "o")])  # fmt: skip
        assert status == 2
        assert sum(bus.packets_to.values()) == 0  # refused before the port was opened
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--others-held is required" in err[0]


@pytest.mark.slow
def test_loaded_joint_recipe_on_the_six_servo_bus(tmp_path):
    """The elbow of the virtual SO-101 (50 g in the gripper, every joint on its own servo):
    record, identify, tune. Not one packet to IDs 1, 2, 4, 5, 6; the elbow's registers read back
    as found; the payload within 3 standard errors; the tuned registers, judged on the truth
    (the published links, 0-100 g), settle within a quarter of LeRobot's P 16 sag, hold without
    tripping the servo's Overload_Torque, at Ms <= 1.6."""
    arm = VirtualArm(payload_kg=0.05)
    with arm.bus() as bus:
        before = sdk_registers(bus.path, "sts3215", ELBOW)
        start = dict(bus.packets_to)
        status = joint.main(["record", "--port", bus.path, "--id", "3", "--joint",
                             "elbow_flex", "--others-held", "--out", str(tmp_path)])  # fmt: skip
        assert status == 0
        after = sdk_registers(bus.path, "sts3215", ELBOW)
        others = {i: bus.packets_to[i] - start.get(i, 0) for i in SO101_IDS if i != ELBOW}
    assert others == {1: 0, 2: 0, 4: 0, 5: 0, 6: 0}
    assert after == before
    records = sorted(tmp_path.glob("elbow_flex_load_*.csv"))
    assert len(records) == 2
    assert joint.main(["identify", *map(str, records), "--joint", "elbow_flex"]) == 0
    doc = json.loads((tmp_path / "elbow_flex_load.json").read_text())
    est = doc["estimate"]
    assert abs(est["values"]["payload_kg"] - 0.05) <= max(3 * est["std"]["payload_kg"], 0.01)
    assert (
        joint.main(
            [
                "tune",
                "--model",
                str(tmp_path / "elbow_flex_load.json"),
                "--trials",
                "60",
                "--polish",
                "120",
                "--out",
                str(tmp_path),
                "--no-progress",
            ]
        )
        == 0
    )
    tuned = json.loads(next(tmp_path.glob("*_registers.json")).read_text())
    regs = RegisterSet.model_validate(tuned["registers"])
    servo = load_bus_servo("sts3215")
    truth = joint_model(servo, "elbow_flex", {}, payload_range_kg=(0.0, 0.1))
    mine, lerobot = judge_loaded(truth, [regs, arm_registers(servo)])
    assert mine.tracking.settled_error_deg <= lerobot.tracking.settled_error_deg / 4
    assert not mine.hold.overload
    assert mine.margins.ms <= 1.6

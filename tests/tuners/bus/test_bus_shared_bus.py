"""The bus commands on an arm's shared bus: six STS3215s, the gripper at ID 6 with calibrated
position limits narrower than the factory's and LeRobot's registers, the other joints at IDs
1-5. The recipe (calibrate, record, identify, tune, deploy) runs on ID 6 and sends the other
servos no packet at all (the scans are broadcast pings); every refusal comes before a byte is
written; an error bit the servo reports stops the command with the torque off."""

from __future__ import annotations

import json
import re

import pytest
from bus_arm import (
    CLOSED,
    FOUND,
    GRIPPER,
    LIMITS,
    OPEN,
    OTHERS,
    arm_bus,
    registers_within_protection,
    sdk_registers,
)
from bus_recipe import SETTINGS as RECIPE_SETTINGS
from bus_recipe import check_deployed, check_identified, check_tuned, perturbed_truth

from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from tuners.bus import calibrate, deploy, identify, record, tune

FAMILY = "sts3215"
SETTINGS = RECIPE_SETTINGS[FAMILY]
#: Where the object sits in the jaws of ID 6 (deg).
OBJECT_DEG = 190.0


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _memories(bus):
    return {i: bytes(bus.table(i).memory) for i in (*OTHERS, GRIPPER)}


@pytest.mark.slow
def test_the_recipe_on_id_6_of_a_six_servo_bus(tmp_path, jaw_file, capsys):
    """The STS3215's end-to-end recipe (``bus_recipe``'s checks: the perturbed truth found, the
    tuned set better than the shipped ones and inside the margins on the truth, deployed and
    read back), on ID 6 of the arm, touching no other servo and leaving ID 6 as found but for
    the saved gains."""
    truth = perturbed_truth(FAMILY)
    out = tmp_path / "arm"
    with arm_bus(FAMILY, truth=truth, object_deg=OBJECT_DEG) as bus:
        table = bus.table(GRIPPER)
        jaw = jaw_file(bus, FAMILY)
        found = sdk_registers(bus.path, FAMILY)
        others = {i: bytes(bus.table(i).memory) for i in OTHERS}
        saves = table.eeprom_saves
        assert record.main(["--port", bus.path, "--id", "6", "--jaw", str(jaw), "--out", str(out),
                            "--settings", *SETTINGS]) == 0  # fmt: skip
        printed = capsys.readouterr().out
        assert "one of 6 servos answering (IDs 1, 2, 3, 4, 5, 6)" in printed
        assert "servo 6 restored and read back (written back: P, acceleration" in printed
        assert "torque reads on (as found)" in printed
        assert sdk_registers(bus.path, FAMILY) == found and table.eeprom_saves == saves
        records = sorted(out.glob("record_*.csv"))
        assert len(records) == 3
        # the records' torque limit is the servo's own (500 as found), not the factory's 1000
        assert all("torque_limit=500 " in r.read_text().splitlines()[0] for r in records)
        assert identify.main([*map(str, records), "--model", FAMILY, "--name", "arm6",
                              "--generations", "20", "--no-plot"]) == 0  # fmt: skip
        model_file = out / "arm6_model.json"
        check_identified(model_file, truth)
        model = load_bus_servo(str(model_file))
        cal = model.calibration  # the owner's jaw came through the records
        assert cal is not None and (cal.servo_id, cal.closed_ticks, cal.open_ticks) == (
            GRIPPER, CLOSED, OPEN)  # fmt: skip
        assert (cal.servo.min_position, cal.servo.max_position) == LIMITS
        # the servo's own protection (LeRobot's Overload_Torque 25 %) came with the records
        assert cal.servo.protection["overload_torque"] == 25
        assert model.protection.overload_duty == 0.25
        capsys.readouterr()
        assert tune.main(["--model", str(model_file), "--trials", "100", "--polish", "200",
                          "--out", str(out), "--no-plot", "--no-progress"]) == 0  # fmt: skip
        printed = capsys.readouterr().out
        assert "note: the hold is judged under servo 6's own protection registers (" in printed
        tuned = json.loads((out / "arm6_registers.json").read_text())
        regs = RegisterSet(**tuned["registers"])
        assert tuned["model"]["calibration"] == cal.model_dump()
        assert regs.torque_limit <= 250, regs  # held under the servo's overload threshold
        check_tuned(tuned, model_file, truth)
        deploy_args = ["--registers", str(out / "arm6_registers.json"), "--port", bus.path,
                       "--id", "6", "--hold", "10", "--no-plot"]  # fmt: skip
        assert deploy.main([*deploy_args, "--save"]) == 0
        printed = capsys.readouterr().out
        assert "hold 10 s: no trip" in printed
        assert "saved p_coefficient, d_coefficient, i_coefficient" in printed
        # kept: the tuned gains (saved to flash, once: one write per adjacent group) ...
        assert (table.get_role("p_gain"), table.get_role("i_gain"), table.get_role("d_gain")) == (
            regs.p, regs.i, regs.d)  # fmt: skip
        assert table.get_role("torque_limit") == regs.torque_limit
        assert 1 <= table.eeprom_saves - saves <= 2
        # ... and the rest as found: the lock, the torque on, holding where it held
        assert table.get_role("lock") == FOUND[FAMILY]["lock"] and table.torque_on
        assert table.get_role("goal_position") == int.from_bytes(found["goal_position"], "little")
        # the other joints got no packet at all: the three scans were broadcast pings
        assert all(bus.packets_to[i] == 0 for i in OTHERS), bus.packets_to
        assert bus.packets_to[0xFE] == 3
        assert {i: bytes(bus.table(i).memory) for i in OTHERS} == others
        bus.power_cycle(GRIPPER)  # the gains survive it; the RAM torque limit is the flash's
        assert (table.get_role("p_gain"), table.get_role("d_gain")) == (regs.p, regs.d)
        assert table.get_role("torque_limit") == table.get_role("max_torque_limit")
        report = json.loads((out / "deploy_arm6" / "report.json").read_text())
        assert report["hold"]["tripped"] is False and report["kept"] is True
        for k in range(4):  # 5 holds of 10 s in all, under Overload_Torque 25: none trips
            assert deploy.main([*deploy_args, "--out", str(out / f"again{k}")]) == 0
            again = json.loads((out / f"again{k}" / "report.json").read_text())
            assert again["hold"]["tripped"] is False, again["hold"]
    assert report["jaw"]["servo_id"] == GRIPPER
    check_deployed(report, tuned["registers"], OBJECT_DEG)


def test_without_an_id_or_with_a_wrong_one_nothing_is_written(tmp_path, jaw_file, capsys):
    with arm_bus(FAMILY) as bus:
        jaw = jaw_file(bus, FAMILY)
        memories = _memories(bus)
        base = ["--port", bus.path, "--jaw", str(jaw), "--out", str(tmp_path / "r")]
        assert record.main(base) == 2
        line = _one_line(capsys.readouterr().err)
        assert line.startswith("python -m tuners.bus.record: error: --id: no servo ID given; "
                               f"the servos that answer on {bus.path} at 1000000 baud: ID 1 "
                               "(STS3215, ")  # fmt: skip
        assert re.findall(r"ID (\d) \(STS3215, ", line) == list("123456"), line
        assert "ID 6 (STS3215, at 2731 ticks)" in line, line
        assert line.endswith("nothing was written to the servo"), line
        j7 = ["--out", str(tmp_path / "j7")]
        assert calibrate.main(["--port", bus.path, "--id", "7", "--closed-ticks", "1760",
                               "--open-ticks", "2940", *j7]) == 2  # fmt: skip
        assert "--id: servo 7 does not answer; the servos that answer" in _one_line(
            capsys.readouterr().err)  # fmt: skip
        assert record.main([*base, "--id", "3"]) == 2  # the calibration is of servo 6
        line = _one_line(capsys.readouterr().err)
        assert "--id 3: the jaw calibration was taken on servo 6" in line
        assert _memories(bus) == memories


def test_refusals_before_a_byte_is_written(tmp_path, jaw_file, capsys):
    with arm_bus(FAMILY) as bus:
        jaw = jaw_file(bus, FAMILY)
        memories = _memories(bus)
        sent = dict(bus.packets_to)
        base = ["--port", bus.path, "--id", "6", "--out", str(tmp_path / "r")]
        # no jaw calibration: the shipped model's angles are never a real servo's
        assert record.main(base) == 2
        assert "--jaw is required" in _one_line(capsys.readouterr().err)
        # a jaw too narrow for the plan's 30 deg steps
        narrow = tmp_path / "narrow.json"
        cal = JawCalibration(family=FAMILY, servo_id=6, closed_ticks=2600, open_ticks=2900)
        narrow.write_text(cal.model_dump_json())
        assert record.main([*base, "--jaw", str(narrow)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert "the record's plan" in line and "outside the calibrated jaw's goal range" in line
        assert dict(bus.packets_to) == sent  # refused before the port was opened
        # the servo was recalibrated since: its limits are not the file's
        moved = json.loads(jaw.read_text())
        moved["calibration"]["servo"]["max_position"] = 3000
        other = tmp_path / "moved.json"
        other.write_text(json.dumps(moved))
        assert record.main([*base, "--jaw", str(other)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert "holds another calibration than the jaw calibration's: max_position 2950" in line
        # a deploy whose torque limit is above the servo's maximum torque limit
        tuned = json.loads(jaw.read_text())
        tuned["calibration"]["servo"]["max_torque_limit"] = 500
        low = tmp_path / "low.json"
        low.write_text(json.dumps(tuned))
        assert deploy.main(["--registers", "results/bus/sts3215_registers.json", "--port",
                            bus.path, "--id", "6", "--jaw", str(low), "--out",
                            str(tmp_path / "d")]) == 2  # fmt: skip
        assert "above the servo's maximum torque limit 500" in _one_line(capsys.readouterr().err)
        assert _memories(bus) == memories
        # registers that hold under the protection read at calibration (Overload_Torque 25 %)
        # but not under what the owner set since (10 %): judged again when the servo is opened
        registers = registers_within_protection(FAMILY, tmp_path)
        bus.table(GRIPPER).store("overload_torque", 10)
        memories = _memories(bus)
        assert deploy.main(["--registers", str(registers), "--port", bus.path, "--id", "6",
                            "--jaw", str(jaw), "--hold", "5", "--out",
                            str(tmp_path / "d2")]) == 2  # fmt: skip
        printed, line = capsys.readouterr()
        assert "note: servo 6's protection registers changed: overload_torque 10 (was 25): the " \
            "registers are judged again under the servo's" in printed, printed  # fmt: skip
        line = _one_line(line)
        r = json.loads(registers.read_text())["registers"]
        named = f"refusing to deploy P={r['p']} I={r['i']} D={r['d']} limit={r['torque_limit']}"
        assert named in line and "overload" in line, line
        assert line.endswith("servo 6 as found and read back (nothing to write back); flash "
                             "untouched; torque reads on (as found)"), line  # fmt: skip
        assert _memories(bus) == memories


def test_an_overload_during_the_hold_stops_the_deploy_with_the_torque_off(tmp_path, jaw_file,
                                                                          capsys):  # fmt: skip
    """The servo trips sooner than its model says (its overload protection lowered to 15 % for
    1 s as the hold begins, after the gate judged the registers under the 25 % it read): TRIPPED
    is an error, the torque goes off, the registers come back, the report is kept."""
    out = tmp_path / "d"
    with arm_bus(FAMILY, object_deg=190.0) as bus:
        jaw = jaw_file(bus, FAMILY)
        found = sdk_registers(bus.path, FAMILY)
        table = bus.table(GRIPPER)

        def lower_at_the_hold(packet) -> None:  # the hold's goal: the closed position
            if packet.id == GRIPPER and packet.instruction == 0x03 and packet.params[0] == 42:
                if int.from_bytes(packet.params[1:3], "little") == CLOSED:
                    table.set("overload_torque", 15)  # what the virtual servo runs by
                    table.set("protection_time", 100)

        bus.on_packet = lower_at_the_hold
        registers = registers_within_protection(FAMILY, tmp_path)
        code = deploy.main(["--registers", str(registers), "--port", bus.path, "--id", "6",
                            "--jaw", str(jaw), "--hold", "3", "--no-plot", "--save", "--out",
                            str(out)])  # fmt: skip
        bus.on_packet = None
        line = _one_line(capsys.readouterr().err)
        assert code == 1, line
        assert "servo 6 TRIPPED during the hold: overload at" in line, line
        assert "servo 6 restored and read back (written back: " in line, line
        assert line.endswith("torque reads off (not as found)"), line
        after = sdk_registers(bus.path, FAMILY)
        assert after.pop("torque_enable") == b"\x00"
        found.pop("torque_enable")
        for name in ("overload_torque", "protection_time"):  # changed by the test, not the deploy
            after.pop(name), found.pop(name)
        assert after == found  # not saved: the trip came first
    report = json.loads((out / "report.json").read_text())
    assert report["hold"]["tripped"] and report["hold"]["first_error"]["errors"] == ["overload"]
    assert report["kept"] is False


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_an_error_bit_during_the_record_stops_it(family, tmp_path, jaw_file, capsys):
    """A servo that overheats at once (in a 69.95 degC room, its limit register at 70 degC):
    the first reply with the bit set ends the record (exit 1, one line naming the bit), the
    torque off, the registers back."""
    shipped = load_bus_servo(family)
    hot = shipped.with_updates(protection=shipped.protection.model_copy(
        update={"ambient_c": 69.95}))  # fmt: skip
    with arm_bus(family, truth=hot) as bus:
        jaw = jaw_file(bus, family)
        found = sdk_registers(bus.path, family)
        settings = ["16,0,32", "32,0,32"] if family == "sts3215" else ["200,0,0", "400,0,0"]
        code = record.main(["--port", bus.path, "--id", "6", "--model", family, "--jaw",
                            str(jaw), "--settings", *settings, "--out",
                            str(tmp_path / "r")])  # fmt: skip
        line = _one_line(capsys.readouterr().err)
        assert code == 1, line
        assert "servo 6" in line and "hardware alert (overheat)" in line, line
        assert "torque reads off" in line, line
        after = sdk_registers(bus.path, family)
        assert after.pop("torque_enable") == b"\x00"
        found.pop("torque_enable")
        assert after == found
        assert not bus.table(GRIPPER).torque_on


@pytest.mark.parametrize(("servo", "joint"), [(2, "shoulder_lift"), (3, "elbow_flex")])
def test_a_joint_under_gravity_is_refused_before_its_record(servo, joint, tmp_path, capsys):
    """The SO-101's shoulder and elbow on the virtual arm's bus (each under the links beyond it),
    calibrated by given positions as if it were the gripper: record's load probe finds the steady
    load gravity puts on it, and stops in one line (exit 2) before the record's large steps, the
    servo restored; the other joints get no packet."""
    from gripper_env.hardware.bus.arm import VirtualArm

    arm = VirtualArm()
    with arm.bus() as bus:
        table = bus.table(servo)
        lo, hi = table.get_role("min_position"), table.get_role("max_position")
        jaw = tmp_path / "jaw.json"
        assert calibrate.main(["--port", bus.path, "--id", str(servo), "--closed-ticks",
                               str(lo + 100), "--open-ticks", str(hi - 100), "--out",
                               str(jaw)]) == 0  # fmt: skip
        capsys.readouterr()
        before = sdk_registers(bus.path, FAMILY, servo)
        goals = [0]
        watch = at_packet_of(bus, servo, goals)
        bus.on_packet = watch
        code = record.main(["--port", bus.path, "--id", str(servo), "--jaw", str(jaw), "--out",
                            str(tmp_path / "r")])  # fmt: skip
        bus.on_packet = None
        printed, err = capsys.readouterr()
        line = _one_line(err)
        assert code == 2, (printed, err)
        assert "load probe: steady load" in printed
        assert "this looks like an arm joint under gravity" in line, line
        assert "--risk-arm-joint" in line and f"servo {servo} restored and read back" in line
        assert sdk_registers(bus.path, FAMILY, servo) == before
        assert all(bus.packets_to[i] == 0 for i in range(1, 7) if i != servo)
        assert 0 < goals[0] < 100  # the probe's creep only, never the record's plan
        assert not list((tmp_path / "r").glob("record_*.csv"))


def at_packet_of(bus, servo, goals):
    """Count the goal writes ``servo`` receives into ``goals[0]``."""
    address = bus.spec.role("goal_position").address

    def watch(packet) -> None:
        if packet.id == servo and packet.instruction == 0x03 and packet.params[:1] == bytes(
                [address]):  # fmt: skip
            goals[0] += 1

    return watch

"""``python -m tuners.bus.calibrate``: the jaw by hand (the command as a subprocess, its prompts
answered on stdin while this process moves the virtual jaw), from LeRobot's calibration file,
and from given positions; the servo's own calibration read and nothing of it written."""

from __future__ import annotations

import json
import subprocess

import pytest
from bus_arm import CLOSED, GRIPPER, HOLDING, LIMITS, OPEN, OTHERS, command, finish, sdk_registers

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.model.bus_calibration import read_jaw_file
from tuners.bus import calibrate


class HandPhysics:
    """A jaw moved by hand: its present position is wherever the test puts it."""

    def __init__(self, ticks: int) -> None:
        self.ticks = ticks

    def advance(self, table: ControlTable, until_s: float) -> None:
        with table.lock:
            table.set_role("present_position", self.ticks)

    def reboot(self, table: ControlTable) -> None:
        pass


def _arm(family: str, hand: HandPhysics, *, torque: int = 1, **registers: int) -> VirtualBus:
    table = ControlTable(family, GRIPPER)
    for role, value in (("min_position", LIMITS[0]), ("max_position", LIMITS[1])):
        f = table.spec.role(role)
        assert table.write(f.address, f.encode(value)) == 0
    for name, value in registers.items():
        f = table.spec.field(name)
        assert table.write(f.address, f.encode(value)) == 0
    table.set_role("goal_position", HOLDING)
    table.set_role("torque_enable", torque)
    return VirtualBus(family, ids=[*OTHERS, table], physics={GRIPPER: hand})


def _expect(proc: subprocess.Popen, text: str) -> None:
    """Read the command's output up to a line holding ``text`` (its prompt)."""
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if text in line:
            return
    pytest.fail(f"no {text!r} in the output: {''.join(seen)}")


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_by_hand_with_the_torque_off_and_back_on(family, tmp_path):
    hand = HandPhysics(HOLDING)
    out = tmp_path / "jaw.json"
    with _arm(family, hand) as bus:
        before = sdk_registers(bus.path, family)
        proc = command("tuners.bus.calibrate", "--port", bus.path, "--id", "6", "--model",
                       family, "--out", str(out), stdin=subprocess.PIPE)  # fmt: skip
        assert proc.stdin is not None
        _expect(proc, "torque is off now (read back; it was on)")
        assert not bus.table(GRIPPER).torque_on
        _expect(proc, "close the jaw fully by hand, then press Enter")
        hand.ticks = 1700  # beyond the servo's min limit: taken at the limit
        proc.stdin.write("\n")
        proc.stdin.flush()
        _expect(proc, "open the jaw fully by hand, then press Enter")
        hand.ticks = 2900
        proc.stdin.write("\n")
        proc.stdin.flush()
        code, stdout, err = finish(proc)
        assert code == 0, err
        assert "torque reads on (as found: on)" in stdout
        assert "the closed position 1700 lies beyond the servo's position limits" in stdout
        after = sdk_registers(bus.path, family)
        assert after == before  # the torque back on, nothing else written
        assert all(bus.packets_to[i] == 0 for i in OTHERS)
    cal = read_jaw_file(out)
    assert (cal.closed_ticks, cal.open_ticks, cal.source) == (LIMITS[0], 2900, "hand-guided")
    assert cal.servo is not None and (cal.servo.min_position, cal.servo.max_position) == LIMITS


def test_stdin_closed_before_enter_restores_the_torque(tmp_path):
    with _arm("sts3215", HandPhysics(HOLDING)) as bus:
        proc = command("tuners.bus.calibrate", "--port", bus.path, "--id", "6", "--out",
                       str(tmp_path / "j.json"))  # stdin is /dev/null  # fmt: skip
        code, _, err = finish(proc)
        assert code == 2
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "pass --closed-ticks and --open-ticks" in lines[0], err
        assert lines[0].endswith("servo 6's torque reads on (as found: on)")
        assert bus.table(GRIPPER).torque_on


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_from_lerobots_calibration_file(family, tmp_path, capsys):
    """LeRobot's file, read as data: its range is the jaw's ends, LeRobot's 0 % the closed one
    (range_max when the motor's drive mode is inverted); it must describe the servo as it is."""
    drive = 1 if family == "xl330" else 0
    extra = {"homing_offset": -37, **({"drive_mode": 1} if drive else {})}
    entry = {"id": GRIPPER, "drive_mode": drive, "homing_offset": -37,
             "range_min": LIMITS[0], "range_max": LIMITS[1]}  # fmt: skip
    arm = tmp_path / "my_arm.json"
    arm.write_text(json.dumps({"shoulder_pan": {**entry, "id": 1}, "gripper": entry}))
    out = tmp_path / "jaw.json"
    with _arm(family, HandPhysics(HOLDING), **extra) as bus:
        before = {i: bytes(bus.table(i).memory) for i in (*OTHERS, GRIPPER)}
        args = ["--port", bus.path, "--id", "6", "--model", family, "--lerobot", str(arm)]
        assert calibrate.main([*args, "--out", str(out)]) == 0
        cal = read_jaw_file(out)
        ends = (LIMITS[1], LIMITS[0]) if drive else LIMITS
        assert (cal.closed_ticks, cal.open_ticks) == ends
        assert cal.servo is not None and cal.servo.homing_offset == -37
        assert cal.servo.drive_mode == drive and cal.source.startswith("lerobot: ")
        assert calibrate.main([*args, "--closed-at", "max", "--out", str(out)]) == 0
        assert read_jaw_file(out).closed_ticks == LIMITS[1]
        # a file of another state of the servo: refused, naming what differs
        arm.write_text(json.dumps({"gripper": {**entry, "homing_offset": 12}}))
        capsys.readouterr()
        assert calibrate.main([*args, "--out", str(tmp_path / "x.json")]) == 2
        line = capsys.readouterr().err.strip()
        assert "homing_offset 12 (the servo holds -37)" in line and "\n" not in line
        assert not (tmp_path / "x.json").exists()
        arm.write_text(json.dumps({"gripper": {**entry, "id": 5}}))
        assert calibrate.main([*args, "--out", str(tmp_path / "x.json")]) == 2
        assert "the motor's id is 5, not --id 6" in capsys.readouterr().err
        after = {i: bytes(bus.table(i).memory) for i in (*OTHERS, GRIPPER)}
        # nothing written to any servo (the gripper's present readings move with its physics)
        present = bus.spec.role("present_position")
        for mem in (after, before):
            mem[GRIPPER] = mem[GRIPPER][: present.address] + mem[GRIPPER][present.end :]
        assert after == before


def test_given_positions_are_checked_against_the_servos_limits(tmp_path, capsys):
    with _arm("sts3215", HandPhysics(HOLDING), torque=0) as bus:
        base = ["--port", bus.path, "--id", "6", "--out", str(tmp_path / "j.json")]
        assert calibrate.main([*base, "--closed-ticks", "1700", "--open-ticks", str(OPEN)]) == 2
        line = capsys.readouterr().err.strip()
        assert "--closed-ticks 1700 lies outside servo 6's position limits [1750, 2950]" in line
        assert calibrate.main([*base, "--closed-ticks", "2000", "--open-ticks", "2030"]) == 2
        assert "deg apart; a jaw needs at least 5 deg" in capsys.readouterr().err
        assert calibrate.main([*base, "--closed-ticks", str(CLOSED), "--open-ticks",
                               str(OPEN)]) == 0  # fmt: skip
        assert "nothing was written to the servo" in capsys.readouterr().out


def test_a_koch_gripper_in_mode_5_is_recorded_and_another_mode_refused(tmp_path, capsys):
    """An XL330 in current-based position mode 5 (LeRobot's koch_follower): calibrated, its
    mode in the calibration, nothing written; extended position (4) is refused in one line,
    exit 2, nothing written."""
    out = tmp_path / "jaw.json"
    args = ["--id", "6", "--model", "xl330", "--closed-ticks", str(CLOSED), "--open-ticks",
            str(OPEN), "--out", str(out)]  # fmt: skip
    present = slice(0, 132)  # up to Present_Position, which the hand moves
    with _arm("xl330", HandPhysics(HOLDING), operating_mode=5) as bus:
        before = bytes(bus.table(GRIPPER).memory[present])
        assert calibrate.main(["--port", bus.path, *args]) == 0
        assert bytes(bus.table(GRIPPER).memory[present]) == before
    cal = read_jaw_file(out)
    assert cal.servo is not None and cal.servo.operating_mode == 5
    assert cal.servo.loop_mode("xl330") == "current_position"
    assert "current-based position control (operating mode 5" in capsys.readouterr().out
    with _arm("xl330", HandPhysics(HOLDING), operating_mode=4) as bus:
        before = bytes(bus.table(GRIPPER).memory[present])
        assert calibrate.main(["--port", bus.path, *args]) == 2
        assert bytes(bus.table(GRIPPER).memory[present]) == before
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "servo 6 is in operating mode 4, not position control or current-based" in line


def test_a_motor_that_is_not_the_gripper_is_refused_before_anything_is_sent(tmp_path, capsys):
    """LeRobot's file names every joint of the arm: only ``gripper`` is taken. Another motor is
    refused in one line, exit 2, before the port is opened (not a packet on the bus); with
    ``--risk-arm-joint`` it is taken, the calibration says so, and record and deploy carry it.
    A calibration of an arm joint written without the flag (an older file) is refused by the
    commands that drive the servo."""
    entry = {"id": GRIPPER, "drive_mode": 0, "homing_offset": 0,
             "range_min": LIMITS[0], "range_max": LIMITS[1]}  # fmt: skip
    arm = tmp_path / "so101_follower.json"
    arm.write_text(json.dumps({"shoulder_pan": entry, "gripper": {**entry, "id": 7}}))
    out = tmp_path / "jaw.json"
    with _arm("sts3215", HandPhysics(HOLDING)) as bus:
        args = ["--port", bus.path, "--id", "6", "--lerobot", str(arm), "--motor", "shoulder_pan",
                "--out", str(out)]  # fmt: skip
        assert calibrate.main(args) == 2
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, err
        assert lines[0].startswith("python -m tuners.bus.calibrate: error: --motor shoulder_pan: "
                                   "refusing a motor that is not the gripper")  # fmt: skip
        assert "--risk-arm-joint" in lines[0] and "nothing was written" in lines[0]
        assert bus.packets_received == 0 and not out.exists()
        assert calibrate.main([*args, "--risk-arm-joint"]) == 0
        cal = read_jaw_file(out)
        assert cal.motor == "shoulder_pan" and cal.arm_joint and cal.risk_arm_joint
        assert "not the gripper" in capsys.readouterr().out
    older = json.loads(out.read_text())  # written before the flag existed: motor in its source
    del older["calibration"]["motor"], older["calibration"]["risk_arm_joint"]
    (tmp_path / "older.json").write_text(json.dumps(older))
    assert read_jaw_file(tmp_path / "older.json").motor == "shoulder_pan"
    from tuners.bus import record

    with _arm("sts3215", HandPhysics(HOLDING)) as bus:
        code = record.main(["--port", bus.path, "--id", "6", "--jaw", str(tmp_path / "older.json"),
                            "--out", str(tmp_path / "rec")])  # fmt: skip
        line = capsys.readouterr().err.strip()
        assert code == 2 and "is a calibration of LeRobot's motor 'shoulder_pan'" in line, line
        assert bus.packets_received == 0

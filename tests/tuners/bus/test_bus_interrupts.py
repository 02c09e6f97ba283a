"""Ctrl-C, SIGTERM and a vanished port in the middle of ``record`` and ``deploy``: the commands
run as subprocesses against a six-servo virtual bus in this process; the signal is sent after a
given number of packets to the gripper (an observable event, never a sleep); then every
writable register of the gripper is read with the vendor's SDK and compared with what it held
before. Nothing is saved to its flash, and the one line the command prints is what it read back.
"""

from __future__ import annotations

import json
import signal
import threading

import pytest
from bus_arm import (
    GRIPPER,
    OTHERS,
    arm_bus,
    at_packet,
    command,
    finish,
    registers_within_protection,
    sdk_registers,
)

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)


def _record(bus, family, jaw, out):
    settings = ["16,0,32", "32,0,32"] if family == "sts3215" else ["200,0,0", "400,0,0"]
    return command("tuners.bus.record", "--port", bus.path, "--id", str(GRIPPER), "--model",
                   family, "--jaw", str(jaw), "--settings", *settings, "--out",
                   str(out))  # fmt: skip


def _deploy(bus, family, jaw, out):
    registers = registers_within_protection(family, out.parent)
    return command("tuners.bus.deploy", "--registers", str(registers), "--port",
                   bus.path, "--id", str(GRIPPER), "--jaw", str(jaw), "--hold", "3",
                   "--no-plot", "--out", str(out))  # fmt: skip


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# when the signal comes: at the 12th packet to the gripper (its registers are being read: 26
# packets open an STS3215, 19 of them its calibration and protection), at the 3rd WRITE (the
# registers are being written), at the 5th, 20th or 100th goal written (the motion: the load
# probe's creep, then the record's plan)
@pytest.mark.parametrize(
    ("family", "which", "at", "sig"),
    [
        ("sts3215", "record", ("packet", 12), signal.SIGINT),
        ("sts3215", "record", ("write", 3), signal.SIGINT),
        ("sts3215", "record", ("goal", 20), signal.SIGINT),
        ("sts3215", "record", ("goal", 100), signal.SIGTERM),
        ("sts3215", "deploy", ("write", 3), signal.SIGINT),
        ("sts3215", "deploy", ("goal", 5), signal.SIGINT),
        ("xl330", "record", ("goal", 20), signal.SIGINT),
        ("xl330", "deploy", ("goal", 5), signal.SIGTERM),
    ],
    ids=lambda v: "-".join(map(str, v)) if isinstance(v, tuple) else None,
)
def test_every_register_is_restored_after_a_signal(family, which, at, sig, tmp_path, jaw_file):
    with arm_bus(family) as bus:
        jaw = jaw_file(bus, family)
        before = sdk_registers(bus.path, family)
        saves = bus.table(GRIPPER).eeprom_saves
        others = {i: bytes(bus.table(i).memory) for i in OTHERS}
        run = _record if which == "record" else _deploy
        proc = run(bus, family, jaw, tmp_path / "out")
        state = at_packet(bus, *at, lambda: proc.send_signal(sig))
        code, out, err = finish(proc)
        bus.on_packet = None
        assert state["acted"], (out, err)
        line = _one_line(err)
        name = signal.Signals(sig).name
        assert code == 128 + sig, (out, err)
        head = f"python -m tuners.bus.{which}: interrupted ({name}); "
        said = line.removeprefix(head)
        assert said != line, line
        if not (at[0] == "packet" and said == "nothing was written to the servo"):  # opening
            assert said.startswith("servo 6 restored and read back (written back: "), line
            assert said.endswith("; torque reads on (as found)"), line
        assert sdk_registers(bus.path, family) == before  # every writable register
        assert bus.table(GRIPPER).eeprom_saves == saves  # nothing saved to flash
        assert bus.table(GRIPPER).torque_on
        for i in OTHERS:  # the other joints: no packet, no byte changed
            assert bus.packets_to[i] == 0 and bytes(bus.table(i).memory) == others[i]
        assert (
            bus.packets_to[0xFE] == 2
        )  # the broadcast pings of calibrate's and the command's scans


@pytest.mark.parametrize("which", ["record", "deploy"])
def test_a_vanished_port_ends_in_one_line_saying_what_was_left_changed(which, tmp_path, jaw_file):
    family = "sts3215"
    with arm_bus(family) as bus:
        jaw = jaw_file(bus, family)
        run = _record if which == "record" else _deploy
        proc = run(bus, family, jaw, tmp_path / "out")
        # at the 5th goal of the motion, the adapter unplugged: the pty's other side is gone
        state = at_packet(bus, "goal", 5, lambda: threading.Thread(target=bus.stop).start())
        code, out, err = finish(proc)
        assert state["acted"], (out, err)
    line = _one_line(err)
    assert code == 1, (out, err)
    assert f"error: the port {bus.path} is gone" in line, line
    assert "servo 6 could not be restored" in line, line
    assert "torque" in line.split("written and not restored:")[1], line  # turned off to write


# ---- deploy --save cut short: the flash ----------------------------------------------------------

_WRITE, _LOCK = 0x03, 55  # Feetech's WRITE instruction; the STS3215's Lock register


def _at_save_write(bus, at: int, act) -> dict[str, int]:
    """Call ``act`` when the gripper receives the ``at``-th WRITE of the save (0: the save's
    ``Lock`` = 0; then the gains' group, the dead zones' group, ``Lock`` = 1), in the bus thread,
    before the reply goes out."""
    state = {"seen": -1, "acted": 0}

    def watch(packet) -> None:
        if packet.id != GRIPPER or packet.instruction != _WRITE or state["acted"]:
            return
        if state["seen"] < 0 and packet.params[:2] == bytes([_LOCK, 0]):
            state["seen"] = 0
        if state["seen"] >= 0:
            if state["seen"] == at:
                state["acted"] = 1
                act()
            state["seen"] += 1

    bus.on_packet = watch
    return state


def _eeprom(table) -> bytes:
    return bytes(table.memory[: table.spec.ram_start])


@pytest.mark.parametrize(
    ("at", "sig"),
    [(0, signal.SIGINT), (1, signal.SIGINT), (1, signal.SIGTERM), (2, signal.SIGTERM),
     (3, signal.SIGINT), (3, signal.SIGTERM)],
)  # fmt: skip
def test_a_save_cut_short_leaves_the_flash_as_found(at, sig, tmp_path, jaw_file):
    """SIGINT or SIGTERM at a write of ``deploy --save`` (the library's test takes every write
    with both): the command exits 128 + the signal, says what it did to the flash, and after a
    power cycle the servo comes up with the owner's gains; every register reads as found."""
    family = "sts3215"
    with arm_bus(family) as bus:
        jaw = jaw_file(bus, family)
        table = bus.table(GRIPPER)
        before = sdk_registers(bus.path, family)
        eeprom = _eeprom(table)
        registers = registers_within_protection(family, tmp_path)
        proc = command("tuners.bus.deploy", "--registers", str(registers), "--port",
                       bus.path, "--id", str(GRIPPER), "--jaw", str(jaw), "--no-plot", "--save",
                       "--out", str(tmp_path / "out"))  # fmt: skip
        state = _at_save_write(bus, at, lambda: proc.send_signal(sig))
        code, out, err = finish(proc)
        bus.on_packet = None
        assert state["acted"], (out, err)
        line = _one_line(err)
        assert code == 128 + sig, (out, err)
        if at == 0:  # Lock 0 written, no group yet
            assert "; flash untouched; torque reads on (as found)" in line, line
        else:
            back = "P 16, D 32, I 0" + (", CW dead zone 1, CCW dead zone 1" if at > 1 else "")
            assert f"; flash written back to the values found ({back}, under Lock 0, read " \
                "back); torque reads on (as found)" in line, line  # fmt: skip
        assert sdk_registers(bus.path, family) == before  # RAM, Lock included, as found
        bus.power_cycle(GRIPPER)
        assert _eeprom(table) == eeprom  # the flash: the owner's
        assert all(bus.packets_to[i] == 0 for i in OTHERS)


def test_a_port_lost_during_a_save_says_what_the_flash_may_hold(tmp_path, jaw_file):
    family = "sts3215"
    with arm_bus(family) as bus:
        jaw = jaw_file(bus, family)
        registers = registers_within_protection(family, tmp_path)
        proc = command("tuners.bus.deploy", "--registers", str(registers), "--port",
                       bus.path, "--id", str(GRIPPER), "--jaw", str(jaw), "--no-plot", "--save",
                       "--out", str(tmp_path / "out"))  # fmt: skip
        state = _at_save_write(bus, 2, lambda: threading.Thread(target=bus.stop).start())
        code, out, err = finish(proc)
        table = bus.table(GRIPPER)
    assert state["acted"], (out, err)
    line = _one_line(err)
    assert code == 1, (out, err)
    assert f"error: the port {bus.path} is gone" in line, line
    sent = json.loads(registers.read_text())["registers"]  # the committed tuned set's gains
    p, d, i = sent["p"], sent["d"], sent["i"]
    assert f"its flash may hold P {p}, D {d}, I {i}, CW dead zone 1, CCW dead zone 1 (saved " \
        "under Lock 0: kept after a power cycle)" in line, line  # fmt: skip
    assert "lock" in line.split("written and not restored:")[1], line
    table.power_cycle()  # what it said: the gains the save sent
    assert (table.get("p_coefficient"), table.get("d_coefficient")) == (p, d)

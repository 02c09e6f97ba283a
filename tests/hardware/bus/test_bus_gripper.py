"""The host's side on a shared bus, against virtual servos: the scan, one ID only, the servo's
calibration read and checked, the snapshot and the restore read back, the STS3215's EEPROM lock
(gains take effect without a save), a save done once, goals inside the servo's limits, the SDK's
busy flag after an interrupted transaction, a vanished port, and signals deferred to the end of
a transaction."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from gripper_env.hardware.bus import BusLink, ControlTable, VirtualBus
from gripper_env.hardware.bus.gripper import (
    BusCalibrationError,
    BusGripper,
    BusSelectError,
    select_servo,
)
from gripper_env.hardware.bus.interrupts import (
    BusInterrupted,
    handle_signals,
    signals_held,
    transaction,
)
from gripper_env.hardware.bus.link import BusModelError, BusPortLostError
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo

LIMITS = (1750, 2950)


def _table(family: str, servo_id: int = 6, **fields: int) -> ControlTable:
    table = ControlTable(family, servo_id)
    for role, value in (("min_position", LIMITS[0]), ("max_position", LIMITS[1])):
        f = table.spec.role(role)
        assert table.write(f.address, f.encode(value)) == 0
    for name, value in fields.items():
        table.set(name, value)
    return table


def _jaw(family: str, closed: int = 1760, opened: int = 2940) -> JawCalibration:
    return JawCalibration(family=family, servo_id=6, closed_ticks=closed, open_ticks=opened)


@pytest.mark.parametrize("family", ["sts3215", "xl330", "xl430"])
def test_the_scan_is_one_broadcast_and_the_session_talks_to_one_id(family):
    with VirtualBus(family, ids=[1, 2, _table(family), 9]) as bus:
        with BusLink(bus.path, family) as link:
            found = link.scan()
            assert sorted(found) == [1, 2, 6, 9] and dict(bus.packets_to) == {0xFE: 1}
            if family != "sts3215":  # a Dynamixel's reply carries its model number
                assert set(found.values()) == {bus.spec.model_number}
            servos = select_servo(link, 6)
            assert [s.servo_id for s in servos] == [1, 2, 6, 9]
            assert bus.packets_to[1] == bus.packets_to[2] == bus.packets_to[9] == 0
            link.restrict(6)
            sent = bus.packets_received
            with pytest.raises(ValueError, match=r"refusing to address servo 2 .* servo 6 only"):
                link.write(2, "torque_enable", 1)
            with pytest.raises(ValueError, match="refusing to address servo 1"):
                link.sync_read("present_position", [6, 1])
            assert bus.packets_received == sent  # refused before anything was sent
            with pytest.raises(BusSelectError, match=r"servo 7 does not answer; the servos that "
                               r"answer on .*: ID 1 \(") as caught:  # fmt: skip
                select_servo(BusLink(bus.path, family), 7)
            assert [s.servo_id for s in caught.value.found] == [1, 2, 6, 9]


def test_no_servo_and_another_model():
    with VirtualBus("xl330", ids=[ControlTable("xl430", 6)]) as bus:
        with BusLink(bus.path, "xl330") as link:
            with pytest.raises(BusModelError, match=r"servo 6 .* is a XL430-W250 .* not the xl330"):
                select_servo(link, 6)
    with VirtualBus("sts3215", ids=[3]) as bus:
        bus.silence(3)
        with BusLink(bus.path, "sts3215") as link:
            with pytest.raises(BusSelectError, match=r"no servo answers on .* and a ping of ID 6"):
                select_servo(link, 6)


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_snapshot_writes_and_restore_read_back(family):
    model = load_bus_servo(family)
    table = _table(family, goal_position=2600)
    table.set_role("p_gain", 20)
    table.set_role("torque_limit", 500)
    table.set_role("torque_enable", 1)
    with VirtualBus(family, ids=[1, table]) as bus:
        found = bytes(table.memory)
        saves = table.eeprom_saves
        regs = model.factory.model_copy(update={"p": 60, "torque_limit": 400})
        with BusGripper(bus.path, model, 6, calibration=_jaw(family)) as jaw:
            assert jaw.found["p_gain"] == 20 and jaw.found["torque_enable"] == 1
            assert jaw.write_registers(regs) == regs
            assert table.get_role("p_gain") == 60 and not table.torque_on
            jaw.torque(True)
            sent = jaw.goal_deg(1000.0)  # clamped into the jaw and the servo's limits
            assert table.get_role("goal_position") == 2940 == jaw.calibration.ticks(sent)
            assert jaw.goal_deg(0.0) == jaw.calibration.deg(1760)
        restored = jaw.restored
        assert restored is not None and restored.ok and restored.torque_on
        assert "P" in restored.written and "goal position" in restored.written
        assert bytes(table.memory[: table.spec.ram_start]) == found[: table.spec.ram_start]
        for role in ("p_gain", "torque_limit", "goal_position", "torque_enable"):
            f = table.spec.role(role)
            assert table.memory[f.address : f.end] == found[f.address : f.end], role
        assert table.eeprom_saves == saves  # the STS's gains were written under Lock = 1
        assert bus.packets_to[1] == 0


def test_the_sts_lock_keeps_gains_out_of_flash_until_a_save():
    model = load_bus_servo("sts3215")
    table = _table("sts3215")
    with VirtualBus("sts3215", ids=[table]) as bus:
        saves = table.eeprom_saves
        tuned = RegisterSet(p=90, i=0, d=100, torque_limit=700, deadband=2)
        with BusGripper(bus.path, model, 6, calibration=_jaw("sts3215")) as jaw:
            jaw.write_registers(tuned)
            assert table.get_role("p_gain") == 90 and table.get_role("lock") == 1
        assert table.eeprom_saves == saves and table.get_role("lock") == 0  # as found
        with BusGripper(bus.path, model, 6, calibration=_jaw("sts3215")) as jaw:
            jaw.write_registers(tuned)
            bus.power_cycle(6)  # the gains were never saved: flash has the factory's
            assert table.get_role("p_gain") == model.factory.p
            jaw.write_registers(tuned)
            saved = jaw.save(tuned)
        assert saved == ["p_coefficient", "d_coefficient", "i_coefficient", "cw_dead_zone",
                         "ccw_dead_zone"]  # fmt: skip
        assert table.eeprom_saves - saves == 2  # one write per adjacent group
        assert table.get_role("torque_limit") == 700 and table.get_role("lock") == 0
        bus.power_cycle(6)
        assert (table.get_role("p_gain"), table.get_role("d_gain")) == (90, 100)


def test_a_mirrored_jaw_and_a_calibration_that_is_not_the_servos():
    model = load_bus_servo("sts3215")
    mirrored = _jaw("sts3215", closed=2900, opened=1800)  # the jaw closes towards larger ticks
    with VirtualBus("sts3215", ids=[_table("sts3215")]) as bus:
        with BusGripper(bus.path, model, 6, calibration=mirrored) as jaw:
            lo, hi = jaw.model.jaw.limits_deg
            assert jaw.goal_range_deg() == pytest.approx((lo, hi))
            jaw.goal_deg(lo)  # the model's closed end ...
            assert bus.table(6).get_role("goal_position") == 2900  # ... is the servo's 2900
            assert jaw.position_deg() == pytest.approx(mirrored.deg(2900))
        other = _jaw("sts3215").with_servo(jaw.servo_registers, 6)
        recalibrated = other.model_copy(
            update={"servo": other.servo.model_copy(update={"homing_offset": 100})}
        )
        before = bytes(bus.table(6).memory)
        with pytest.raises(BusCalibrationError, match=r"homing_offset 0 .the calibration says 100"):
            BusGripper(bus.path, model, 6, calibration=recalibrated)
        with pytest.raises(BusCalibrationError, match="taken on servo 5, not 6"):
            BusGripper(bus.path, model, 6, calibration=_jaw("sts3215").model_copy(
                update={"servo_id": 5}))  # fmt: skip
        with pytest.raises(ValueError, match="no jaw calibration"):
            BusGripper(bus.path, model, 6)
        with pytest.raises(BusSelectError, match="no servo ID given"):
            BusGripper(bus.path, model, None, calibration=_jaw("sts3215"))
        assert bytes(bus.table(6).memory) == before


def test_current_based_position_mode_runs_its_model_and_the_torque_limit_kept_under_the_max():
    """An XL330 in mode 5 (the Koch gripper as LeRobot configures it): the family's model runs
    current-based position control, its goal current written within the servo's Current_Limit
    and restored; a model identified in position control, or a mode no model describes
    (extended position, 4), is refused with nothing written."""
    model = load_bus_servo("xl330")
    table = _table("xl330", operating_mode=5, current_limit=900, goal_current=800)
    with VirtualBus("xl330", ids=[table]) as bus:
        before = bytes(table.memory)
        with BusGripper(bus.path, model, 6, calibration=_jaw("xl330")) as jaw:
            assert jaw.model.current_mode and jaw.found["goal_current"] == 800
            regs = RegisterSet(p=400, d=2000, torque_limit=885, goal_current=600)
            assert jaw.write_registers(regs) == regs
            assert table.get("goal_current") == 600 and table.get("operating_mode") == 5
            with pytest.raises(ValueError, match="goal current 1000 is above servo 6's current"):
                jaw.write_registers(regs.model_copy(update={"goal_current": 1000}))
            with pytest.raises(ValueError, match="goal current 0 for servo 6"):
                jaw.write_registers(regs.model_copy(update={"goal_current": 0}))
        assert jaw.restored is not None and jaw.restored.ok
        assert bytes(table.memory)[:64] == before[:64]  # EEPROM: mode 5 and the limit kept
        assert table.get("goal_current") == 800 and table.get("position_p_gain") == 400
        with pytest.raises(RuntimeError, match="cut short"):  # an error: restored the same
            with BusGripper(bus.path, model, 6, calibration=_jaw("xl330")) as jaw:
                jaw.write_registers(regs)
                raise RuntimeError("cut short")
        assert "goal current" in jaw.restored.written and jaw.restored.ok
        assert table.get("goal_current") == 800 and table.get("operating_mode") == 5
        identified = model.calibrated(_jaw("xl330").with_servo(jaw.servo_registers, 6))
        position = identified.with_updates(operating_mode="position")
        with pytest.raises(BusCalibrationError, match=r"operating mode 5 \(current-based "
                           r"position control\), not position control \(3\)"):  # fmt: skip
            BusGripper(bus.path, position, 6)
        assert bytes(table.memory)[:64] == before[:64]
    with VirtualBus("xl330", ids=[_table("xl330", operating_mode=4)]) as bus:
        with pytest.raises(BusCalibrationError, match=r"operating mode 4 \(which no model"):
            BusGripper(bus.path, model, 6, calibration=_jaw("xl330"))
    table = _table("sts3215")
    f = table.spec.role("max_torque_limit")
    assert table.write(f.address, f.encode(500)) == 0
    with VirtualBus("sts3215", ids=[table]) as bus:
        with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
            before = bytes(table.memory)
            regs = RegisterSet(p=32, d=32, torque_limit=800, deadband=1)
            with pytest.raises(ValueError, match="torque limit 800 is above servo 6's maximum"):
                jaw.write_registers(regs)
            assert bytes(table.memory) == before


def test_a_transaction_cut_short_leaves_the_sdk_busy_and_the_next_one_works():
    """A KeyboardInterrupt inside an SDK call (outside the commands' deferral) leaves
    PortHandler.is_using set: every later call failed with 'port busy' before."""
    with VirtualBus("sts3215", ids=[_table("sts3215")]) as bus:
        with BusLink(bus.path, "sts3215") as link:
            link._port.is_using = True  # what the interrupted transaction left behind
            link.write(6, "torque_enable", 1)
            assert bus.table(6).torque_on


def test_a_vanished_port_is_one_error():
    bus = VirtualBus("sts3215", ids=[_table("sts3215")]).start()
    link = BusLink(bus.path, "sts3215")
    assert link.read(6, "p_gain") == 32
    bus.stop()
    with pytest.raises(BusPortLostError, match=f"the port {bus.path} is gone"):
        link.read(6, "p_gain")
    link.close()  # quietly


def test_signals_wait_for_the_end_of_a_transaction():
    # as found: Python's handler, or SIG_IGN when the suite runs as a shell's background job
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with handle_signals():
        with pytest.raises(BusInterrupted) as caught:
            with transaction():
                os.kill(os.getpid(), signal.SIGTERM)
                inside = True  # the handler ran here and only noted the signal
        assert inside and caught.value.name == "SIGTERM" and caught.value.exit_status == 143
        with signals_held() as came:
            with transaction():
                os.kill(os.getpid(), signal.SIGINT)
        assert came == ["SIGINT"]  # held: noted, not raised
        with pytest.raises(BusInterrupted, match="SIGINT"):  # between transactions: at once
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(60)  # interrupted by the handler, never waited out
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_keep_torque_holds_where_it_is_and_an_unchanged_group_is_not_saved_again():
    table = _table("sts3215")  # found: torque off, unlocked (the factory's Lock 0)
    with VirtualBus("sts3215", ids=[table]) as bus:
        saves = table.eeprom_saves
        tuned = RegisterSet(p=90, i=0, d=100, torque_limit=700, deadband=1)  # dead zones as found
        with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
            jaw.write_registers(tuned)
            jaw.torque(True)
            sent = jaw.goal_deg(jaw.model.jaw.open_deg)
            assert jaw.save(tuned) == ["p_coefficient", "d_coefficient", "i_coefficient"]
            jaw.keep_torque = True
        assert table.eeprom_saves - saves == 1  # the gains' group, once
        assert table.torque_on and table.get_role("goal_position") == jaw.calibration.ticks(sent)
        restored = jaw.restored
        assert restored is not None and restored.ok and restored.torque_on
        assert not restored.torque_as_found and "torque reads on (not as found)" in (
            restored.describe())  # fmt: skip


# ---- a save that does not finish ----------------------------------------------------------------

#: The owner's registers, in flash and RAM alike (as LeRobot's configure leaves them: it writes
#: under Lock 0), and the registers a deploy saves.
_OWNERS = {"p_coefficient": 20, "d_coefficient": 30, "i_coefficient": 0, "cw_dead_zone": 1,
           "ccw_dead_zone": 1}  # fmt: skip
_TUNED = RegisterSet(p=122, i=2, d=119, torque_limit=700, deadband=3)


def _owners_table(lock: int) -> ControlTable:
    table = _table("sts3215")
    for name, value in _OWNERS.items():
        table.store(name, value)
    table.set("lock", lock)
    table.set("torque_enable", 1)
    table.set_role("goal_position", 2600)
    return table


def _flash(table: ControlTable) -> bytes:
    return bytes(table._saved)  # the flash image a power cycle loads


def _writes_to_six(packet) -> bool:
    return packet.id == 6 and packet.instruction == 0x03  # Feetech WRITE


def _save_writes(lock: int) -> int:
    """The WRITE packets a whole save sends (counted on a servo found with ``lock``)."""
    table = _owners_table(lock)
    count = [0]
    with VirtualBus("sts3215", ids=[table]) as bus:
        with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
            jaw.write_registers(_TUNED)
            bus.on_packet = lambda p: count.__setitem__(0, count[0] + _writes_to_six(p))
            jaw.save(_TUNED)
            bus.on_packet = None
    return count[0]


@pytest.mark.parametrize("lock", [1, 0])
def test_a_save_cut_short_at_any_write_leaves_the_flash_as_found(lock):
    """SIGINT and SIGTERM at each WRITE a save sends (the lock, each adjacent group under
    Lock 0, the lock again, the RAM registers): after a power cycle the flash holds the owner's
    registers, the lock reads as found, and the restore's message says what it did to the flash,
    as read back."""
    writes = _save_writes(lock)
    assert writes >= 4  # Lock 0, two groups (gains, dead zones), Lock 1
    for k in range(writes):
        for sig in (signal.SIGINT, signal.SIGTERM):
            table = _owners_table(lock)
            flash, saves = _flash(table), table.eeprom_saves
            seen = [0]

            def at_kth_write(packet, k=k, sig=sig, seen=seen):
                if _writes_to_six(packet):
                    if seen[0] == k:
                        os.kill(os.getpid(), sig)  # comes while the host waits for the reply
                    seen[0] += 1

            with VirtualBus("sts3215", ids=[table]) as bus, handle_signals():
                with pytest.raises(BusInterrupted, match=signal.Signals(sig).name):
                    with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
                        jaw.write_registers(_TUNED)
                        bus.on_packet = at_kth_write
                        jaw.save(_TUNED)
                bus.on_packet = None
                restored = jaw.restored
                assert restored is not None and restored.ok, (k, sig, restored)
                said = restored.describe()
                assert table.get("lock") == lock and table.torque_on, (k, sig, said)
                if k == 0:  # Lock 0 was written, no group yet: the flash was never written
                    assert "flash untouched" in said and table.eeprom_saves == saves, said
                else:  # the groups sent so far (the gains', then the dead zones') go back
                    back = "P 20, D 30, I 0" + (
                        ", CW dead zone 1, CCW dead zone 1" if k > 1 else ""
                    )
                    assert (
                        f"flash written back to the values found ({back}, under Lock 0, "
                        "read back)" in said
                    ), (k, said)
                bus.power_cycle(6)
                assert _flash(table) == flash, (k, sig, said)
                assert {n: table.get(n) for n in _OWNERS} == _OWNERS, (k, sig)


def test_a_finished_save_is_kept_and_says_so():
    table = _owners_table(1)
    with VirtualBus("sts3215", ids=[table]) as bus:
        with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
            jaw.write_registers(_TUNED)
            jaw.save(_TUNED)
        said = jaw.restored.describe()
        assert "flash keeps the saved P 122, D 119, I 2, CW dead zone 3, CCW dead zone 3" in said
        bus.power_cycle(6)
        assert (table.get("p_coefficient"), table.get("d_coefficient")) == (122, 119)


def test_a_port_lost_during_a_save_names_what_the_flash_may_hold():
    table = _owners_table(1)
    seen = [0]
    with VirtualBus("sts3215", ids=[table]) as bus:

        def vanish_after_the_first_group(packet):
            if _writes_to_six(packet):
                seen[0] += 1
                if seen[0] == 2:  # Lock 0, then the gains' group: the adapter is unplugged
                    threading.Thread(target=bus.stop).start()

        with pytest.raises(BusPortLostError) as caught:
            with BusGripper(bus.path, "sts3215", 6, calibration=_jaw("sts3215")) as jaw:
                jaw.write_registers(_TUNED)
                bus.on_packet = vanish_after_the_first_group
                jaw.save(_TUNED)
    said = jaw.restored.describe()
    assert said in caught.value.__notes__
    assert "could not be restored (the port" in said and "lock" in said, said
    assert "its flash may hold P 122, D 119, I 2 (saved under Lock 0" in said, said
    table.power_cycle()
    assert (table.get("p_coefficient"), table.get("d_coefficient")) == (122, 119)  # as it said

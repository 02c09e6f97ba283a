"""The virtual servos behave as the real ones do where a host can tell: the baud rate, the homing
offset, protection from the servo's own registers (LeRobot's SO-follower settings, the XL330's
torque cut), current-based position mode, prompt replies after a long idle, and the protection
registers read back over a link. Device time comes from a clock the test advances: nothing
here sleeps for the physics."""

from __future__ import annotations

import math

import dynamixel_sdk as dx
import numpy as np
import pytest
import scservo_sdk as scs

from gripper_env.hardware.bus.link import BusLink
from gripper_env.hardware.bus.protection import configured_model, read_protection_registers
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.model.bus_servo import load_bus_servo, protection_from_registers
from gripper_env.sim import bus_servo as core


class Clock:
    """Device time the test sets (s)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _sts(bus: VirtualBus, baud: int = 1_000_000):
    port = scs.PortHandler(bus.path)
    assert port.openPort() and port.setBaudRate(baud)
    return port, scs.PacketHandler(0)


def _dxl(bus: VirtualBus, baud: int = 1_000_000):
    port = dx.PortHandler(bus.path)
    assert port.openPort() and port.setBaudRate(baud)
    return port, dx.PacketHandler(2.0)


# ---- the line ------------------------------------------------------------------------------


def test_the_servo_answers_only_at_its_baud_rate():
    with VirtualBus("sts3215", ids=(6,)) as bus:
        port, ph = _sts(bus, 500_000)
        assert ph.ping(port, 6)[1] == scs.COMM_RX_TIMEOUT  # factory: 1 Mbaud
        assert port.setBaudRate(1_000_000)
        assert ph.ping(port, 6) == (777, scs.COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 6, 6, 3)[0] == scs.COMM_SUCCESS  # Baud_Rate 3: 128000
        assert ph.ping(port, 6)[1] == scs.COMM_RX_TIMEOUT
        assert port.setBaudRate(128_000)  # a custom rate (TCSETS2): the servo hears it
        assert ph.ping(port, 6) == (777, scs.COMM_SUCCESS, 0)
        assert bus.line_baud == 128_000
        port.closePort()
    with VirtualBus("xl330", ids=(1,)) as bus:  # factory 57600
        port, ph = _dxl(bus)
        assert ph.ping(port, 1)[1] == dx.COMM_RX_TIMEOUT
        assert port.setBaudRate(57_600)
        assert ph.ping(port, 1) == (1200, dx.COMM_SUCCESS, 0)
        port.closePort()


# ---- the homing offset ---------------------------------------------------------------------


def test_sts_homing_offset_shifts_present_position_and_goal():
    clock = Clock()
    unit = ServoUnit("sts3215")
    dpt = unit.model.deg_per_tick
    with VirtualBus("sts3215", physics=unit, clock=clock) as bus:
        port, ph = _sts(bus)
        actual = round(unit.angle_deg / dpt)  # 2731: the jaw open at 240 deg
        assert ph.read2ByteTxRx(port, 1, 56)[0] == actual
        offset = actual - 2047
        assert ph.write2ByteTxRx(port, 1, 31, offset)[0] == scs.COMM_SUCCESS  # sign-magnitude
        assert ph.read2ByteTxRx(port, 1, 56)[0] == 2047  # present = actual - offset
        ph.write2ByteTxRx(port, 1, 31, scs.SCS_TOSCS(-1000, 11))  # negative: wraps mod 4096
        assert ph.read2ByteTxRx(port, 1, 56)[0] == (actual + 1000) % 4096
        ph.write2ByteTxRx(port, 1, 31, offset)
        ph.write1ByteTxRx(port, 1, 40, 1)
        ph.write2ByteTxRx(port, 1, 42, 2047 - 300)  # a goal in the offset frame
        clock.t = 2.0
        present = ph.read2ByteTxRx(port, 1, 56)[0]
        band = unit.model.physics.static / (unit.model.scale.kp * 32) + 2
        band += unit.model.physics.backlash_deg / dpt
        assert abs(present - (2047 - 300)) <= band
        assert abs(unit.angle_deg / dpt - (2047 - 300 + offset)) <= band + 1  # the true shaft
        port.closePort()


def test_dynamixel_homing_offset_adds_and_is_ignored_beyond_1024_in_position_mode():
    clock = Clock()
    unit = ServoUnit("xl330")
    actual = round(unit.angle_deg / unit.model.deg_per_tick)
    with VirtualBus("xl330", physics=unit, clock=clock, baudrate=1_000_000) as bus:
        port, ph = _dxl(bus)
        assert ph.write4ByteTxRx(port, 1, 20, (2047 - actual) & 0xFFFFFFFF)[1] == 0
        assert ph.read4ByteTxRx(port, 1, 132)[0] == 2047  # present = actual + offset
        assert ph.write4ByteTxRx(port, 1, 20, 1500)[1] == 0
        assert ph.read4ByteTxRx(port, 1, 132)[0] == actual  # e-manual: ignored in mode 3
        assert ph.write1ByteTxRx(port, 1, 11, 5)[1] == 0  # current-based position: it counts
        assert ph.read4ByteTxRx(port, 1, 132)[0] == actual + 1500
        port.closePort()


# ---- protection from the registers ---------------------------------------------------------


def _stall_sts(overload_torque: int) -> tuple[int, int, ServoUnit]:
    """LeRobot's SO-follower gripper settings (Max_Torque_Limit 500, Protection_Current 250,
    Overload_Torque as given), a power cycle, and a 4 s stall closing on an object; the status
    byte and the load register after it."""
    clock = Clock()
    unit = ServoUnit("sts3215")
    m = unit.model
    unit.place_object(m.jaw.object_deg)
    with VirtualBus("sts3215", physics=unit, clock=clock) as bus:
        port, ph = _sts(bus)
        ph.write2ByteTxRx(port, 1, 16, 500)  # Max_Torque_Limit (EEPROM, saved: Lock 0)
        ph.write2ByteTxRx(port, 1, 28, 250)  # Protection_Current
        ph.write1ByteTxRx(port, 1, 36, overload_torque)  # Overload_Torque
        bus.power_cycle()  # Torque_Limit comes up from Max_Torque_Limit
        assert ph.read2ByteTxRx(port, 1, 48)[0] == 500
        ph.write1ByteTxRx(port, 1, 40, 1)
        ph.write2ByteTxRx(port, 1, 42, round(m.jaw.limits_deg[0] / m.deg_per_tick))
        clock.t = 4.0
        status, _, error = ph.read1ByteTxRx(port, 1, 65)
        load = ph.read2ByteTxRx(port, 1, 60)[0] & 0x3FF
        assert status == error  # the status register is every reply's error byte
        port.closePort()
    return status, load, unit


def test_lerobot_overload_torque_25_trips_a_4_s_stall_and_the_factory_80_does_not():
    status, load, unit = _stall_sts(25)
    assert status & 0x20  # overload: 50 % > 25 % for Protection_Time 2 s
    assert not status & 0x08  # 50 % of 2.7 A is 1.35 A, under Protection_Current 1.625 A
    assert load == pytest.approx(200, abs=5)  # Protective_Torque 20 %
    assert unit.running_model.protection.overload_duty == 0.25
    status, load, _ = _stall_sts(80)
    assert status == 0 and load == pytest.approx(500, abs=5)  # holds at its torque limit


def test_sts_over_current_trips_on_protection_current():
    clock = Clock()
    unit = ServoUnit("sts3215", object_deg=185.0)
    m = unit.model
    with VirtualBus("sts3215", physics=unit, clock=clock) as bus:
        port, ph = _sts(bus)
        ph.write2ByteTxRx(port, 1, 28, 250)  # 1.625 A; at full torque the stall takes 2.7 A
        ph.write1ByteTxRx(port, 1, 38, 50)  # Over_Current_Protection_Time 0.5 s
        ph.write1ByteTxRx(port, 1, 40, 1)
        ph.write2ByteTxRx(port, 1, 42, round(m.jaw.limits_deg[0] / m.deg_per_tick))
        clock.t = 1.0
        status = ph.read1ByteTxRx(port, 1, 65)[0]
        assert status & 0x08 and not status & 0x20  # over-current before the 2 s overload
        current = ph.read2ByteTxRx(port, 1, 69)[0]
        assert current * 0.0065 == pytest.approx(0.2 * 2.7, abs=0.02)  # protective torque 20 %
        port.closePort()


@pytest.mark.parametrize(("family", "cut"), [("xl330", True), ("xl430", False)])
def test_dynamixel_shutdown_zero_xl330_still_cuts_its_torque(family, cut):
    """Shutdown 0: the XL430 detects nothing and holds on; the XL330 cuts its torque on an
    overload all the same (reported on the issue tracker)."""
    clock = Clock()
    unit = ServoUnit(family, object_deg=185.0)
    m = unit.model
    with VirtualBus(family, physics=unit, clock=clock, baudrate=1_000_000) as bus:
        port, ph = _dxl(bus)
        assert ph.write1ByteTxRx(port, 1, 63, 0)[1] == 0  # Shutdown 0 (EEPROM, torque off)
        ph.write1ByteTxRx(port, 1, 64, 1)
        ph.write4ByteTxRx(port, 1, 116, round(m.jaw.limits_deg[0] / m.deg_per_tick))
        clock.t = 5.0
        torque, _, error = ph.read1ByteTxRx(port, 1, 64)
        status = ph.read1ByteTxRx(port, 1, 70)[0]
        if cut:
            assert torque == 0 and status == 0x20 and error & 0x80
        else:
            assert torque == 1 and status == 0 and not error & 0x80
        port.closePort()


def test_protection_is_read_from_the_servo_over_a_link():
    model = load_bus_servo("sts3215")
    with VirtualBus("sts3215", ids=(6,)) as bus, BusLink(bus.path, "sts3215", ids=(6,)) as link:
        table = bus.table(6)
        table.set("overload_torque", 25)
        table.set("protection_current", 250)
        table.set("unloading_condition", 32)
        values = read_protection_registers(link, 6)
        assert values == {name: table.get(name) for name in values}
        configured = configured_model(link, 6, model)
    pr = configured.protection
    assert (pr.overload_duty, pr.overload_time_s, pr.tripped_duty) == (0.25, 2.0, 0.2)
    assert pr.overcurrent_a == pytest.approx(1.625) and pr.acts_on == ("overload",)
    assert configured.physics == model.physics and configured.scale == model.scale
    # the factory registers give the shipped model's protection
    factory = {f.name: f.default for f in table.spec if f.name in values}
    assert protection_from_registers(model, factory) == model.protection


# ---- current-based position mode -------------------------------------------------------------


def test_current_based_position_tracks_and_holds_its_goal_current():
    """Mode 5, Goal Current 300 mA, P 600 D 3000: the free jaw reaches its goal; pressed on an
    object the motor holds 300 mA, a force of 300 / 1470 of the stall force (hand-worked: the
    current loop holds the torque, the torque is the current's fraction of the stall current;
    the jaw without friction, so that the object alone balances it)."""
    clock = Clock()
    shipped = load_bus_servo("xl330")  # without friction, the force balance is exact
    m = shipped.with_updates(
        physics=shipped.physics.model_copy(update={"coulomb": 0.0, "static": 0.0})
    )
    unit = ServoUnit(m)
    dpt = m.deg_per_tick
    with VirtualBus("xl330", physics=unit, clock=clock, baudrate=1_000_000) as bus:
        port, ph = _dxl(bus)
        assert ph.write1ByteTxRx(port, 1, 11, 5)[1] == 0
        assert ph.write2ByteTxRx(port, 1, 102, 300)[1] == 0  # Goal Current (mA)
        ph.write2ByteTxRx(port, 1, 84, 600)  # P and D: a current loop has no back-EMF damping
        ph.write2ByteTxRx(port, 1, 80, 3000)
        ph.write1ByteTxRx(port, 1, 64, 1)
        goal = round(220.0 / dpt)
        ph.write4ByteTxRx(port, 1, 116, goal)
        clock.t = 1.0
        present = ph.read4ByteTxRx(port, 1, 132)[0]
        assert abs(present - goal) <= 10  # within a degree: static friction over the gain
        assert unit.running_model.operating_mode == "current_position"
        unit.place_object(185.0)
        ph.write4ByteTxRx(port, 1, 116, round(150.0 / dpt))
        clock.t = 2.5
        raw = ph.read2ByteTxRx(port, 1, 126)[0]
        current = raw - 65536 if raw & 0x8000 else raw  # signed: closing is negative
        assert current == pytest.approx(-300, abs=3)
        assert unit.force_n == pytest.approx(300 / 1470 * m.stall_force_n(), rel=0.02)
        port.closePort()


# ---- idle time -------------------------------------------------------------------------------


def test_a_reply_after_300_s_idle_is_prompt_and_the_state_exact():
    """300 s of device time between two instructions, holding an object: the unit runs a few
    hundred ticks through the core and skips the rest in closed form, and ends where running
    every tick ends (trip tick, temperature)."""
    clock = Clock()
    unit = ServoUnit("sts3215", object_deg=185.0)
    m = unit.model
    goal = round(m.jaw.limits_deg[0] / m.deg_per_tick)
    with VirtualBus("sts3215", physics=unit, clock=clock) as bus:
        port, ph = _sts(bus)
        ph.write2ByteTxRx(port, 1, 48, 300)  # 30 %: no overload (80 %), the winding warms
        ph.write1ByteTxRx(port, 1, 40, 1)
        ph.write2ByteTxRx(port, 1, 42, goal)
        start = unit.ticks_simulated
        clock.t = 300.0
        temperature, result, _ = ph.read1ByteTxRx(port, 1, 63)
        assert result == scs.COMM_SUCCESS
        assert unit.ticks_simulated - start < 3000 and unit.ticks_skipped > 295_000
        port.closePort()
    # every tick through the core, from the same start
    regs = m.factory.model_copy(update={"torque_limit": 300})
    params = core.bus_params(m, with_object=True)
    params[core.PB_OBJ] = 185.0
    state = core.bus_state(m)[None].copy()
    run = core.run_bus(
        params[None], core.bus_registers(m, regs)[None], state, np.full((1, 300_000), goal)
    )
    assert temperature == round(run.temperature[0, -1])
    assert unit.temperature_c == pytest.approx(run.temperature[0, -1], rel=1e-9)
    assert unit.angle_deg == state[0, core.SB_TH]


def test_skipped_rests_stop_at_a_protection_event():
    """An overload 2 s into a hold: the skip stops short of it and the core trips on the same
    tick as running every tick does."""
    m = load_bus_servo("sts3215")
    goal = round(m.jaw.limits_deg[0] / m.deg_per_tick)
    params = core.bus_params(m, with_object=True)
    state = core.bus_state(m)[None].copy()
    run = core.run_bus(params[None], core.bus_registers(m, m.factory)[None], state,
                       np.full((1, 6000), goal))  # fmt: skip
    trip_tick = int(np.argmax(run.trip[0] > 0))
    assert 1990 < trip_tick < 2500
    unit = ServoUnit(m, object_deg=m.jaw.object_deg)
    clock = Clock()
    with VirtualBus("sts3215", physics=unit, clock=clock) as bus:
        table = bus.table(1)
        table.write(40, b"\x01")
        table.write(42, goal.to_bytes(2, "little"))
        for k in range(1, 7):
            clock.t = float(k)
            port, ph = _sts(bus)
            ph.ping(port, 1)
            port.closePort()
            if k * 1000 >= trip_tick + 1:
                assert unit.trip == core.TRIP_OVERLOAD
            elif k * 1000 < trip_tick:
                assert unit.trip == core.TRIP_NONE
    assert unit.ticks_skipped > 0 and math.isclose(unit.angle_deg, state[0, core.SB_TH])

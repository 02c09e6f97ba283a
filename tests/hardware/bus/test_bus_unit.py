"""The virtual bus servos with their physics (the simulation core's bus-servo block) behind
the control table, driven by the vendors' own SDKs: the jaw goes where the goal says, and an
overload on an object shows in the error byte as a real servo shows it."""

from __future__ import annotations

import time

import dynamixel_sdk as dxl
import pytest
import scservo_sdk as scs

from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit


def _wait(seconds):
    time.sleep(seconds)


def test_sts3215_follows_the_goal_and_trips_on_an_object():
    unit = ServoUnit("sts3215")
    m = unit.model
    with VirtualBus("sts3215", ids=(1,), physics=unit, speed=4.0) as bus:
        port = scs.PortHandler(bus.path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        ph = scs.PacketHandler(0)
        assert ph.write1ByteTxRx(port, 1, 40, 1)[0] == scs.COMM_SUCCESS  # torque on
        goal = round(200.0 / m.deg_per_tick)
        assert ph.write2ByteTxRx(port, 1, 42, goal)[0] == scs.COMM_SUCCESS
        _wait(0.5)  # 2 s of device time
        pos, res, err = ph.read2ByteTxRx(port, 1, 56)
        assert res == scs.COMM_SUCCESS and err == 0
        # within the dead band static friction leaves at the factory P = 32
        band = m.physics.static / (m.scale.kp * m.factory.p) + 2
        assert abs(pos - goal) <= band
        # an object in the jaws, closed on at full torque limit: the overload trips in 2 s
        unit.place_object(m.jaw.object_deg)
        ph.write2ByteTxRx(port, 1, 42, round(m.jaw.limits_deg[0] / m.deg_per_tick))
        _wait(1.0)  # 4 s of device time
        _, res, err = ph.read1ByteTxRx(port, 1, 65)
        assert res == scs.COMM_SUCCESS
        assert err & 0x20 and "Overload" in ph.getRxPacketError(err)
        load, _, _ = ph.read2ByteTxRx(port, 1, 60)
        # the STS keeps its protective torque (20 %): the load register says 200 (0.1 %)
        assert (load & 0x3FF) == pytest.approx(1000 * m.protection.tripped_duty, abs=5)
        port.closePort()


def test_xl330_overload_turns_the_torque_off_until_a_reboot():
    unit = ServoUnit("xl330", object_deg=None)
    m = unit.model
    with VirtualBus("xl330", ids=(1,), physics=unit, speed=4.0, baudrate=1_000_000) as bus:
        port = dxl.PortHandler(bus.path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        ph = dxl.PacketHandler(2.0)
        model_number, res, _ = ph.ping(port, 1)
        assert res == dxl.COMM_SUCCESS and model_number == 1200
        assert ph.write1ByteTxRx(port, 1, 64, 1)[0] == dxl.COMM_SUCCESS
        unit.place_object(m.jaw.object_deg)
        ph.write4ByteTxRx(port, 1, 116, round(m.jaw.limits_deg[0] / m.deg_per_tick))
        _wait(1.0)
        torque, res, err = ph.read1ByteTxRx(port, 1, 64)
        assert res == dxl.COMM_SUCCESS and torque == 0 and err & 0x80
        status, _, _ = ph.read1ByteTxRx(port, 1, 70)
        assert status & 0x20  # Hardware Error Status: overload
        # torque cannot come back on while in alert; a REBOOT clears it
        ph.write1ByteTxRx(port, 1, 64, 1)
        assert ph.read1ByteTxRx(port, 1, 64)[0] == 0
        assert ph.reboot(port, 1)[0] == dxl.COMM_SUCCESS
        _wait(0.1)
        status, res, err = ph.read1ByteTxRx(port, 1, 70)
        assert res == dxl.COMM_SUCCESS and status == 0 and not err & 0x80
        assert ph.write1ByteTxRx(port, 1, 64, 1)[0] == dxl.COMM_SUCCESS
        assert ph.read1ByteTxRx(port, 1, 64)[0] == 1
        port.closePort()

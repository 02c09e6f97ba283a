"""The virtual bus itself: when it runs the servos' physics, what it does with a physics that
fails, and with the host's broken packets."""

from __future__ import annotations

import time

import pytest
import serial

from gripper_env.hardware.bus import ControlTable, Physics, VirtualBus
from gripper_env.hardware.bus import dynamixel as dxl
from gripper_env.hardware.bus import feetech as scs


class Recording:
    """A physics that records its calls and moves the present position by one tick each."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.reboots = 0
        self.writes: list[set[str]] = []

    def advance(self, table: ControlTable, until_s: float) -> None:
        self.times.append(until_s)
        self.writes.append(table.pop_writes())
        table.set_role("present_position", table.get_role("present_position") + 1)

    def reboot(self, table: ControlTable) -> None:
        self.reboots += 1


#: How long a reply may take (s): the servo's thread shares a loaded machine's CPU with the test
#: (threads went unscheduled for up to 0.5 s at load 15). A reply ends the wait at once.
REPLY_WAIT_S = 10.0
#: How long to listen where no reply is due (s): a late reply would only make such a test pass.
SILENCE_S = 0.3


def _exchange(port: serial.Serial, packet: bytes, size: int, wait_s: float = REPLY_WAIT_S) -> bytes:
    port.reset_input_buffer()
    port.write(packet)
    deadline = time.monotonic() + wait_s
    data = b""
    while len(data) < size and time.monotonic() < deadline:
        data += port.read(size - len(data))
    return data


def _until(condition, wait_s: float = REPLY_WAIT_S) -> bool:
    """Wait for ``condition()`` (the servo's thread to get there), at most ``wait_s``."""
    deadline = time.monotonic() + wait_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)
    return condition()


def test_physics_runs_before_every_packet_on_device_time():
    clock = iter(range(100))
    one, two = Recording(), Recording()
    assert isinstance(one, Physics)
    with VirtualBus("xl330", ids=(1, 2), physics={1: one, 2: two}, baudrate=1_000_000,
                    clock=lambda: float(next(clock))) as bus:  # fmt: skip
        with serial.Serial(bus.path, 1_000_000, timeout=0.2) as port:
            ping = dxl.encode_instruction(1, dxl.INST_PING)
            assert dxl.decode_packet(_exchange(port, ping, 14)).data == b"\xb0\x04\x34"
            write = dxl.encode_instruction(2, dxl.INST_WRITE, b"\x40\x00\x01")  # torque on
            assert dxl.decode_packet(_exchange(port, write, 11)).error == 0
            read = dxl.encode_instruction(2, dxl.INST_READ, b"\x84\x00\x04\x00")
            reply = dxl.decode_packet(_exchange(port, read, 15))
            assert int.from_bytes(reply.data, "little") == 2048 + 3
            reboot = dxl.encode_instruction(2, dxl.INST_REBOOT)
            assert dxl.decode_packet(_exchange(port, reboot, 11)).error == 0
    assert one.times == two.times == [0.0, 1.0, 2.0, 3.0]
    assert two.writes[:3] == [set(), set(), {"torque_enable"}]
    assert (one.reboots, two.reboots) == (0, 1)


def test_a_failing_physics_stops_the_bus_loudly():
    class Broken:
        def advance(self, table: ControlTable, until_s: float) -> None:
            raise ZeroDivisionError("the model blew up")

        def reboot(self, table: ControlTable) -> None:
            pass

    bus = VirtualBus("sts3215", physics=Broken()).start()
    with serial.Serial(bus.path, 1_000_000, timeout=0.1) as port:
        assert _exchange(port, scs.encode_instruction(1, scs.INST_PING), 6, SILENCE_S) == b""
    with pytest.raises(RuntimeError, match="the model blew up"):
        bus.stop()


def test_a_half_packet_is_forgotten_after_the_interbyte_timeout():
    with VirtualBus("sts3215") as bus, serial.Serial(bus.path, 1_000_000, timeout=0.2) as port:
        ping = scs.encode_instruction(1, scs.INST_PING)
        port.write(ping[:4])  # the host gave up half-way
        # the servo drops them once 20 ms pass without a byte (on its own clock, after it
        # read them: sent before then, the next packet would be glued to them)
        assert _until(lambda: bus.garbage_bytes == 4)
        assert scs.decode_packet(_exchange(port, ping, 6)) == scs.Packet(1, 0, b"")
        bad = bytearray(ping)
        bad[-1] ^= 0xFF
        assert _exchange(port, bytes(bad), 6, SILENCE_S) == b""
        assert _until(lambda: bus.bad_packets == 1)


def test_broadcast_ping_answers_in_id_order_and_silence():
    with VirtualBus("sts3215", ids=(3, 1, 2)) as bus:
        bus.silence(2)
        with serial.Serial(bus.path, 1_000_000, timeout=0.2) as port:
            data = _exchange(port, scs.encode_instruction(scs.BROADCAST_ID, scs.INST_PING), 12)
        assert [p.id for p in scs.Parser().feed(data)] == [1, 3]
        assert bus.ids == [3, 1, 2]


def test_the_bus_checks_its_servos_and_physics():
    with pytest.raises(ValueError, match="one physics each"):
        VirtualBus("sts3215", ids=(1, 2), physics=Recording())
    with pytest.raises(ValueError, match="not on the bus: \\[5\\]"):
        VirtualBus("sts3215", ids=(1,), physics={5: Recording()})
    with pytest.raises(ValueError, match="cannot share a feetech bus"):
        VirtualBus("sts3215", ids=[ControlTable("xl330")])
    with pytest.raises(ValueError, match="speed must be > 0"):
        VirtualBus("xl330", speed=0)
    with pytest.raises(RuntimeError, match="not started"):
        _ = VirtualBus("xl330").path
    with VirtualBus("xl430", ids=(4,)) as bus, pytest.raises(KeyError, match="IDs: \\[4\\]"):
        bus.table(1)


def test_power_cycle_restores_the_saved_eeprom():
    physics = Recording()
    with VirtualBus("sts3215", physics=physics) as bus:
        table = bus.table(1)
        table.write(55, b"\x01")  # lock: EEPROM writes are not saved
        table.write(21, b"\x05")
        bus.power_cycle()
        assert table.get("p_coefficient") == 32 and physics.reboots == 1

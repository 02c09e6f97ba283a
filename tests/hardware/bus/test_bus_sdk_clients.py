"""The vendors' SDKs, used directly, as independent clients of the virtual servos: what they
send must be understood and what the servos answer must decode in the SDKs as a real servo's
reply (values, error bits and their texts, failures)."""

from __future__ import annotations

from collections.abc import Iterator

import dynamixel_sdk as dx
import pytest
import scservo_sdk as scs

from gripper_env.hardware.bus import VirtualBus

IDS = (1, 2, 3)


@pytest.fixture
def sts() -> Iterator[tuple[VirtualBus, object, object]]:
    with VirtualBus("sts3215", ids=IDS) as bus:
        port = scs.PortHandler(bus.path)
        ph = scs.PacketHandler(0)  # STS: little-endian (the SDK's global byte order)
        assert port.openPort()
        try:
            yield bus, port, ph
        finally:
            port.closePort()


@pytest.fixture
def xl() -> Iterator[tuple[VirtualBus, object, object]]:
    with VirtualBus("xl330", ids=IDS, baudrate=1_000_000) as bus:  # as LeRobot sets it
        port = dx.PortHandler(bus.path)
        ph = dx.PacketHandler(2.0)
        assert port.setBaudRate(1_000_000)  # the broadcast ping waits 0.8 s (1.4 s at 57600)
        try:
            yield bus, port, ph
        finally:
            port.closePort()


# ---- Feetech: scservo_sdk --------------------------------------------------------------------


def test_sts_ping_read_write(sts):
    bus, port, ph = sts
    for servo_id in IDS:
        assert ph.ping(port, servo_id) == (777, scs.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 2, 56) == (2048, scs.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, 21, 20) == (scs.COMM_SUCCESS, 0)  # P coefficient
    assert ph.read1ByteTxRx(port, 2, 21) == (20, scs.COMM_SUCCESS, 0)
    assert bus.table(2).get_role("p_gain") == 20
    assert ph.write2ByteTxRx(port, 2, 42, 1000) == (scs.COMM_SUCCESS, 0)  # goal position
    assert ph.read2ByteTxRx(port, 2, 56) == (1000, scs.COMM_SUCCESS, 0)  # mirrored
    assert bus.table(1).get("goal_position") == 2048  # the others did not move


def test_sts_negative_positions_are_sign_magnitude(sts):
    bus, port, ph = sts
    assert ph.write2ByteTxRx(port, 1, 42, scs.SCS_TOSCS(-100, 15)) == (scs.COMM_SUCCESS, 0)
    assert bus.table(1).read(42, 2) == bytes([100, 0x80])
    raw, result, _ = ph.read2ByteTxRx(port, 1, 56)
    assert result == scs.COMM_SUCCESS and scs.SCS_TOHOST(raw, 15) == -100


def test_sts_group_sync_write_and_read(sts):
    bus, port, ph = sts
    writer = scs.GroupSyncWrite(port, ph, 42, 2)
    for servo_id in IDS:
        goal = 1000 + 100 * servo_id
        assert writer.addParam(servo_id, [scs.SCS_LOBYTE(goal), scs.SCS_HIBYTE(goal)])
    before = bus.replies_sent
    assert writer.txPacket() == scs.COMM_SUCCESS
    reader = scs.GroupSyncRead(port, ph, 56, 2)
    for servo_id in (3, 1, 2):  # replies come in the order asked
        assert reader.addParam(servo_id)
    assert reader.txRxPacket() == scs.COMM_SUCCESS
    assert {i: reader.getData(i, 56, 2) for i in IDS} == {1: 1100, 2: 1200, 3: 1300}
    assert bus.replies_sent == before + 3  # none to the sync write


def test_sts_sync_read_of_a_missing_servo_fails(sts):
    bus, port, ph = sts
    bus.silence(2)
    reader = scs.GroupSyncRead(port, ph, 56, 2)
    for servo_id in IDS:
        reader.addParam(servo_id)
    assert reader.txRxPacket() == scs.COMM_RX_TIMEOUT
    assert ph.ping(port, 2)[1] == scs.COMM_RX_TIMEOUT
    bus.silence(2, False)
    assert ph.ping(port, 2) == (777, scs.COMM_SUCCESS, 0)


@pytest.mark.parametrize(
    ("bits", "text"),
    [
        (0x01, "[RxPacketError] Input voltage error!"),
        (0x02, "[RxPacketError] Angle sen error!"),
        (0x04, "[RxPacketError] Overheat error!"),
        (0x08, "[RxPacketError] OverEle error!"),
        (0x20, "[RxPacketError] Overload error!"),
    ],
)
def test_sts_status_bits_reach_the_sdk(sts, bits, text):
    bus, port, ph = sts
    bus.table(3).set_role("error_status", bits)
    value, result, error = ph.read2ByteTxRx(port, 3, 56)
    assert (value, result, error) == (2048, scs.COMM_SUCCESS, bits)
    assert ph.getRxPacketError(error) == text
    assert ph.ping(port, 1) == (777, scs.COMM_SUCCESS, 0)


def test_sts_corrupted_truncated_and_noisy_replies(sts):
    bus, port, ph = sts
    bus.corrupt_replies(1)
    _, result, _ = ph.read2ByteTxRx(port, 1, 56)
    assert result == scs.COMM_RX_CORRUPT
    assert ph.getTxRxResult(result) == "[TxRxResult] Incorrect status packet!"
    bus.truncate_replies(1)
    assert ph.read2ByteTxRx(port, 1, 56)[1] == scs.COMM_RX_CORRUPT
    bus.inject_garbage(b"\x00\x13\xff\x42")
    assert ph.read2ByteTxRx(port, 1, 56) == (2048, scs.COMM_SUCCESS, 0)
    bus.drop_replies(1)
    assert ph.read2ByteTxRx(port, 1, 56)[1] == scs.COMM_RX_TIMEOUT
    assert ph.read2ByteTxRx(port, 1, 56) == (2048, scs.COMM_SUCCESS, 0)


def test_sts_response_level_zero_answers_reads_only(sts):
    _, port, ph = sts
    assert ph.write1ByteTxRx(port, 1, 8, 0) == (scs.COMM_SUCCESS, 0)  # response status level
    assert ph.write1ByteTxRx(port, 1, 41, 10)[0] == scs.COMM_RX_TIMEOUT  # no reply ...
    assert ph.read1ByteTxRx(port, 1, 41) == (10, scs.COMM_SUCCESS, 0)  # ... but written


def test_sts_refuses_silently_and_keeps_eeprom_open_with_torque_on(sts):
    bus, port, ph = sts
    assert ph.write1ByteTxRx(port, 1, 40, 1) == (scs.COMM_SUCCESS, 0)  # torque on
    assert ph.write1ByteTxRx(port, 1, 22, 16) == (scs.COMM_SUCCESS, 0)  # D coefficient (EEPROM)
    assert ph.read1ByteTxRx(port, 1, 22) == (16, scs.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 21, 255) == (scs.COMM_SUCCESS, 0)  # beyond 254: refused
    assert ph.read1ByteTxRx(port, 1, 21) == (32, scs.COMM_SUCCESS, 0)  # unchanged
    assert ph.write1ByteTxRx(port, 1, 56, 0) == (scs.COMM_SUCCESS, 0)  # read-only: refused
    assert bus.table(1).get("present_position") == 2048


def test_sts_reg_write_then_broadcast_action(sts):
    bus, port, ph = sts
    for servo_id in (1, 2):
        assert ph.regWriteTxRx(port, servo_id, 42, 2, [0x00, 0x04]) == (scs.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, 64) == (1, scs.COMM_SUCCESS, 0)  # asynchronous write flag
    assert bus.table(1).get("goal_position") == 2048
    assert ph.action(port, scs.BROADCAST_ID) == scs.COMM_SUCCESS
    assert ph.read2ByteTxRx(port, 2, 56) == (1024, scs.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 3, 56) == (2048, scs.COMM_SUCCESS, 0)


# ---- Dynamixel: dynamixel_sdk ------------------------------------------------------------------


def test_xl_ping_read_write(xl):
    bus, port, ph = xl
    for servo_id in IDS:
        assert ph.ping(port, servo_id) == (1200, dx.COMM_SUCCESS, 0)
    found, result = ph.broadcastPing(port)
    assert result == dx.COMM_SUCCESS and found == {i: [1200, 52] for i in IDS}
    assert ph.read4ByteTxRx(port, 2, 132) == (2048, dx.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 2, 116, 1500) == (dx.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 2, 132) == (1500, dx.COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 2, 84, 800) == (dx.COMM_SUCCESS, 0)  # position P gain
    assert ph.read2ByteTxRx(port, 2, 84) == (800, dx.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 2, 104, -100 & 0xFFFFFFFF) == (dx.COMM_SUCCESS, 0)
    assert bus.table(2).get("goal_velocity") == -100


def test_xl_group_sync_write_and_read(xl):
    bus, port, ph = xl
    writer = dx.GroupSyncWrite(port, ph, 116, 4)
    for servo_id in IDS:
        goal = 500 * servo_id
        assert writer.addParam(servo_id, list(goal.to_bytes(4, "little")))
    assert writer.txPacket() == dx.COMM_SUCCESS
    reader = dx.GroupSyncRead(port, ph, 132, 4)
    for servo_id in (2, 3, 1):
        assert reader.addParam(servo_id)
    assert reader.txRxPacket() == dx.COMM_SUCCESS
    assert {i: reader.getData(i, 132, 4) for i in IDS} == {1: 500, 2: 1000, 3: 1500}
    bus.silence(3)
    assert reader.txRxPacket() == dx.COMM_RX_TIMEOUT


def test_xl_refuses_eeprom_writes_with_torque_on(xl):
    bus, port, ph = xl
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (dx.COMM_SUCCESS, 0)  # torque on
    result, error = ph.write1ByteTxRx(port, 1, 7, 5)  # ID (EEPROM)
    assert (result, error) == (dx.COMM_SUCCESS, 7)
    assert ph.getRxPacketError(error) == (
        "[RxPacketError] Writing or Reading is not available to target address!"
    )
    assert bus.table(1).servo_id == 1
    assert ph.write1ByteTxRx(port, 1, 64, 0) == (dx.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 7, 5) == (dx.COMM_SUCCESS, 0)
    assert ph.ping(port, 5) == (1200, dx.COMM_SUCCESS, 0)


def test_xl_range_limit_and_length_errors(xl):
    _, port, ph = xl
    _, error = ph.write2ByteTxRx(port, 1, 100, 900)  # goal PWM beyond 885
    assert ph.getRxPacketError(error) == "[RxPacketError] The data value is out of range!"
    assert ph.write2ByteTxRx(port, 1, 36, 300) == (dx.COMM_SUCCESS, 0)  # PWM limit
    _, error = ph.write2ByteTxRx(port, 1, 100, 400)
    assert ph.getRxPacketError(error) == "[RxPacketError] The data value exceeds the limit value!"
    _, error = ph.write2ByteTxRx(port, 1, 116, 0)  # half of the goal position
    assert ph.getRxPacketError(error) == (
        "[RxPacketError] The data length does not match as expected!"
    )
    txpacket = [0] * 10
    txpacket[4], txpacket[5], txpacket[7] = 1, 3, 0x07  # an instruction no servo knows
    _, result, error = ph.txRxPacket(port, txpacket)
    assert result == dx.COMM_SUCCESS
    undefined = "[RxPacketError] Undefined instruction or incorrect instruction!"
    assert ph.getRxPacketError(error) == undefined


def test_xl_hardware_alert_and_reboot(xl):
    bus, port, ph = xl
    table = bus.table(2)
    table.set_role("error_status", table.spec.error_bits["overload"])
    value, result, error = ph.read4ByteTxRx(port, 2, 132)
    assert (value, result, error) == (2048, dx.COMM_SUCCESS, 0x80)
    assert ph.getRxPacketError(error) == (
        "[RxPacketError] Hardware error occurred. Check the error at Control Table "
        "(Hardware Error Status)!"
    )
    assert ph.read1ByteTxRx(port, 2, 70) == (0x20, dx.COMM_SUCCESS, 0x80)
    result, error = ph.write1ByteTxRx(port, 2, 64, 1)  # torque on: refused in alert
    assert (result, error) == (dx.COMM_SUCCESS, 0x81)
    assert ph.reboot(port, 2) == (dx.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 2, 70) == (0, dx.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (dx.COMM_SUCCESS, 0)


def test_xl_corrupted_and_missing_replies(xl):
    bus, port, ph = xl
    bus.corrupt_replies(1)
    _, result, _ = ph.read4ByteTxRx(port, 1, 132)
    assert ph.getTxRxResult(result) == "[TxRxResult] Incorrect status packet!"
    assert ph.read4ByteTxRx(port, 1, 132) == (2048, dx.COMM_SUCCESS, 0)
    _, result, _ = ph.ping(port, 9)
    assert ph.getTxRxResult(result) == "[TxRxResult] There is no status packet!"


def test_xl_byte_stuffing_both_ways(xl):
    bus, port, ph = xl
    # goal PWM -1 and goal current -3: the payload holds FF FF FD, stuffed by the SDK
    assert ph.writeTxRx(port, 1, 100, 4, [0xFF, 0xFF, 0xFD, 0xFF]) == (dx.COMM_SUCCESS, 0)
    assert (bus.table(1).get("goal_pwm"), bus.table(1).get("goal_current")) == (-1, -3)
    data, result, error = ph.readTxRx(port, 1, 100, 4)  # stuffed by the servo
    assert (data, result, error) == ([0xFF, 0xFF, 0xFD, 0xFF], dx.COMM_SUCCESS, 0)


def test_xl_status_return_level(xl):
    _, port, ph = xl
    assert ph.write1ByteTxRx(port, 3, 68, 1) == (dx.COMM_SUCCESS, 0)  # PING and READ only
    assert ph.write4ByteTxRx(port, 3, 116, 100)[0] == dx.COMM_RX_TIMEOUT
    assert ph.read4ByteTxRx(port, 3, 116) == (100, dx.COMM_SUCCESS, 0)
    assert ph.ping(port, 3) == (1200, dx.COMM_SUCCESS, 0)

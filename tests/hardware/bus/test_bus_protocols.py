"""The two wire protocols against hand-worked packets: the e-manual's Protocol 2.0 examples,
the Feetech checksum, the SDKs' own CRC and byte stuffing, and the parsers' resynchronisation."""

from __future__ import annotations

import dynamixel_sdk
import pytest
import scservo_sdk
from hypothesis import given, settings
from hypothesis import strategies as st

from gripper_env.hardware.bus import dynamixel as dxl
from gripper_env.hardware.bus import feetech as scs


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# ---- Dynamixel Protocol 2.0: the e-manual's examples (ID 1 is an XM430-W210, model 1030) -------

EMANUAL = [
    # (instruction packet, its fields, status packet, its error and parameters)
    ("FF FF FD 00 01 03 00 01 19 4E", (1, dxl.INST_PING, b""),
     "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D", h("06 04 26")),
    ("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", (1, dxl.INST_READ, h("84 00 04 00")),
     "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0", h("A6 00 00 00")),
    ("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", (1, dxl.INST_WRITE, h("74 00 00 02 00 00")),
     "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
    ("FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E",
     (1, dxl.INST_REG_WRITE, h("68 00 C8 00 00 00")), "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
    ("FF FF FD 00 01 03 00 05 02 CE", (1, dxl.INST_ACTION, b""),
     "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
    ("FF FF FD 00 01 03 00 08 2F 4E", (1, dxl.INST_REBOOT, b""),
     "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
    ("FF FF FD 00 01 04 00 06 01 A1 E6", (1, dxl.INST_FACTORY_RESET, h("01")),
     "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
    ("FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", (1, dxl.INST_CLEAR, h("01 44 58 4C 22")),
     "FF FF FD 00 01 04 00 55 00 A1 0C", b""),
]  # fmt: skip


@pytest.mark.parametrize(("instruction", "fields", "status", "data"), EMANUAL)
def test_emanual_examples_encode_and_decode(instruction, fields, status, data):
    packet_id, inst, params = fields
    assert dxl.encode_instruction(packet_id, inst, params) == h(instruction)
    assert dxl.decode_packet(h(instruction)) == dxl.Packet(packet_id, inst, params)
    assert dxl.encode_status(packet_id, 0, data) == h(status)
    reply = dxl.decode_packet(h(status))
    assert (reply.is_status, reply.error, reply.data) == (True, 0, data)


def test_emanual_broadcast_ping_sync_and_bulk_examples():
    assert dxl.encode_instruction(0xFE, dxl.INST_PING) == h("FF FF FD 00 FE 03 00 01 31 42")
    assert dxl.encode_status(2, 0, h("06 04 26")) == h("FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D")
    sync_read = h("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA")
    assert dxl.encode_instruction(0xFE, dxl.INST_SYNC_READ, h("84 00 04 00 01 02")) == sync_read
    assert dxl.encode_status(2, 0, h("1F 08 00 00")) == h(
        "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"
    )
    sync_write = h("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87")
    params = h("74 00 04 00 01 96 00 00 00 02 AA 00 00 00")
    assert dxl.encode_instruction(0xFE, dxl.INST_SYNC_WRITE, params) == sync_write
    bulk_read = h("FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05")
    params = h("01 90 00 02 00 02 92 00 01 00")
    assert dxl.encode_instruction(0xFE, dxl.INST_BULK_READ, params) == bulk_read
    assert dxl.encode_status(1, 0, h("77 00")) == h("FF FF FD 00 01 06 00 55 00 77 00 C3 69")
    assert dxl.encode_status(2, 0, h("24")) == h("FF FF FD 00 02 05 00 55 00 24 8B A9")


@given(st.binary(max_size=64))
def test_crc_is_the_sdks(data):
    sdk = dynamixel_sdk.Protocol2PacketHandler()
    assert dxl.crc16(data) == sdk.updateCRC(0, list(data), len(data))


def _stuffy() -> st.SearchStrategy[bytes]:
    """Bytes rich in FF and FD, so that FF FF FD patterns are common."""
    return st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x55]), max_size=40).map(bytes)


@given(_stuffy())
def test_byte_stuffing_round_trips(body):
    stuffed = dxl.stuff(body)
    assert dxl.unstuff(stuffed) == body
    assert b"\xff\xff\xfd\x00" not in stuffed  # no header inside a packet
    if b"\xff\xff\xfd" in body:
        assert len(stuffed) > len(body)


@given(st.integers(0, 252), st.sampled_from([2, 3, 4, 0x55]), _stuffy())
@settings(max_examples=60)
def test_stuffed_packets_are_the_sdks_and_decode(packet_id, inst, params):
    ours = dxl.encode_packet(packet_id, inst, params)
    # the SDK's own framing: addStuffing then the CRC, as its txPacket does
    sdk = dynamixel_sdk.Protocol2PacketHandler()
    raw = [0xFF, 0xFF, 0xFD, 0x00, packet_id, 0, 0, inst, *params, 0, 0]
    length = len(params) + 3
    raw[5], raw[6] = length & 0xFF, length >> 8
    raw = list(sdk.addStuffing(raw))
    total = (raw[5] | raw[6] << 8) + 7
    crc = sdk.updateCRC(0, raw, total - 2)
    raw[total - 2 : total] = [crc & 0xFF, crc >> 8]
    assert ours == bytes(raw[:total])
    assert dxl.decode_packet(ours) == dxl.Packet(packet_id, inst, params)


def test_dynamixel_parser_resyncs_on_garbage_and_bad_crc():
    good1 = dxl.encode_status(1, 0, h("A6 00 00 00"))
    good2 = dxl.encode_status(2, 0x80, b"")
    bad = bytearray(dxl.encode_status(3, 0, b"\x01"))
    bad[-1] ^= 0xFF
    stream = b"\x00\xff\xff\xfd\x12" + good1 + bytes(bad) + b"\xff\xff" + good2
    for chunking in (len(stream), 1, 3):
        parser = dxl.Parser()
        packets = []
        for k in range(0, len(stream), chunking):
            packets += parser.feed(stream[k : k + chunking])
        assert [p.id for p in packets] == [1, 2]
        assert packets[1].error == 0x80
        assert parser.bad_crc == 1
        assert parser.pending == 0
        assert parser.garbage_bytes == len(stream) - len(good1) - len(good2)


def test_dynamixel_decode_refuses_a_bad_packet():
    with pytest.raises(ValueError, match="not one valid"):
        dxl.decode_packet(h("FF FF FD 00 01 03 00 01 19 4F"))


# ---- Feetech SCS/STS ----------------------------------------------------------------------------


def test_feetech_ping_checksum():
    assert scs.encode_instruction(1, scs.INST_PING) == h("FF FF 01 02 01 FB")
    assert scs.checksum(h("01 02 01")) == 0xFB
    assert scs.encode_status(1, 0) == h("FF FF 01 02 00 FC")
    # READ of present position (56, 2 bytes) from ID 3, and a reply of 1000 (0x03E8)
    assert scs.encode_instruction(3, scs.INST_READ, h("38 02")) == h("FF FF 03 04 02 38 02 BC")
    assert scs.decode_packet(h("FF FF 03 04 00 E8 03 0D")) == scs.Packet(3, 0, h("E8 03"))


class _CapturePort:
    """Stands in for the SDK's PortHandler (its method names): keeps what txPacket writes."""

    is_using = False

    def __init__(self) -> None:
        self.sent = b""

    def clearPort(self) -> None:
        pass

    def writePort(self, packet: list[int]) -> int:
        self.sent = bytes(packet)
        return len(packet)


def test_feetech_packets_are_the_sdks():
    sdk = scservo_sdk.PacketHandler(0)
    port = _CapturePort()
    sdk.writeTxOnly(port, 1, 42, 2, [0x00, 0x08])
    assert port.sent == scs.encode_instruction(1, scs.INST_WRITE, h("2A 00 08"))
    sdk.syncWriteTxOnly(port, 42, 2, [1, 0x00, 0x08, 2, 0x10, 0x00], 6)
    params = h("2A 02 01 00 08 02 10 00")
    assert port.sent == scs.encode_instruction(0xFE, scs.INST_SYNC_WRITE, params)
    port.setPacketTimeout = lambda n: None
    sdk.syncReadTx(port, 56, 2, [1, 2, 3], 3)
    assert port.sent == scs.encode_instruction(0xFE, scs.INST_SYNC_READ, h("38 02 01 02 03"))


def test_feetech_parser_resyncs_on_garbage_and_bad_checksum():
    good1 = scs.encode_status(1, 0x20, h("00 08"))
    good2 = scs.encode_status(2, 0, b"")
    bad = bytearray(scs.encode_status(3, 0, h("01 02")))
    bad[-1] ^= 0x01
    stream = b"\x13\xff" + good1 + bytes(bad) + b"\x00\xff" + good2
    for chunking in (len(stream), 1, 2):
        parser = scs.Parser()
        packets = []
        for k in range(0, len(stream), chunking):
            packets += parser.feed(stream[k : k + chunking])
        assert packets == [scs.Packet(1, 0x20, h("00 08")), scs.Packet(2, 0, b"")]
        assert parser.bad_checksum == 1
        assert parser.pending == 0


@given(st.integers(0, 253), st.integers(0, 255), st.binary(max_size=30), st.binary(max_size=8))
@settings(max_examples=60)
def test_feetech_packets_survive_leading_garbage(packet_id, code, params, garbage):
    packet = scs.encode_packet(packet_id, code, params)
    parser = scs.Parser()
    found = parser.feed(garbage.replace(b"\xff", b"") + packet)
    assert found == [scs.Packet(packet_id, code, params)]

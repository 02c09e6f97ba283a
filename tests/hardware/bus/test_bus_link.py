"""The host's link through the vendors' SDKs, against the virtual servos: values by name,
read-back verification, and one clear error for each way a transaction fails."""

from __future__ import annotations

import re
import threading
import time

import pytest
import scservo_sdk

from gripper_env.hardware.bus import (
    BusAlertError,
    BusCorruptError,
    BusLink,
    BusModelError,
    BusPortError,
    BusServoError,
    BusTimeoutError,
    BusUnsupportedError,
    BusVerifyError,
    ControlTable,
    VirtualBus,
)
from gripper_env.hardware.bus.gripper import FACTORY_BAUD


class DeafToGains(ControlTable):
    """A servo that acknowledges writes to its P gain but keeps the old value."""

    def write(self, address: int, data: bytes) -> int:
        if address == self.spec.role("p_gain").address:
            return 0
        return super().write(address, data)


@pytest.mark.parametrize("family", ["sts3215", "xl330", "xl430"])
def test_read_write_by_name_and_role(family, reply_ms):
    with (
        VirtualBus(family, ids=(1, 2)) as bus,
        BusLink(bus.path, family, ids=(1, 2), timeout_ms=reply_ms) as link,
    ):
        assert link.ping_all() == {1: bus.spec.model_number, 2: bus.spec.model_number}
        link.write(1, "p_gain", 20)  # a role ...
        assert bus.table(1).get_role("p_gain") == 20
        assert link.read(1, bus.spec.roles["p_gain"]) == 20  # ... or the vendor's name
        if family != "sts3215":  # the position limits bind in position control mode:
            with pytest.raises(BusServoError, match="data limit error"):
                link.write(2, "goal_position", -100)
            link.write(2, "operating_mode", 4)  # extended position control
        link.write(2, "goal_position", -100)  # signed: sign-magnitude or two's complement
        assert link.read(2, "present_position") == -100
        link.torque(2, True)
        assert bus.table(2).torque_on
        link.sync_write("goal_position", {1: 1000, 2: 3000}, verify=True)
        assert link.sync_read("present_position") == {1: 1000, 2: 3000}
        assert link.sync_read("present_position", [2]) == {2: 3000}
        link.write_many(1, {"acceleration": 5, "velocity_limit": 100})
        assert link.read(1, "acceleration") == 5


def test_sts_values_are_immune_to_the_sdks_global_byte_order(reply_ms):
    with VirtualBus("sts3215") as bus, BusLink(bus.path, "sts3215", timeout_ms=reply_ms) as link:
        scservo_sdk.SCS_SETEND(1)  # someone else made a big-endian (SCS) packet handler
        try:
            link.write(1, "goal_position", 1000)
            assert bus.table(1).get("goal_position") == 1000
            assert link.read(1, "present_position") == 1000
            assert link.sync_read("present_position") == {1: 1000}
            link.sync_write("goal_position", {1: 300})
            assert link.read(1, "goal_position") == 300
            assert link.ping(1) == 777
        finally:
            scservo_sdk.SCS_SETEND(0)


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_a_write_that_does_not_stick_fails_verification(family, reply_ms):
    table = DeafToGains(family, servo_id=1)
    with (
        VirtualBus(family, ids=[table]) as bus,
        BusLink(bus.path, family, timeout_ms=reply_ms) as link,
    ):
        gain = bus.spec.roles["p_gain"]
        default = bus.spec.field(gain).default
        with pytest.raises(BusVerifyError) as caught:
            link.write(1, "p_gain", 7)
        assert str(caught.value) == (
            f"servo 1 on {bus.path}: wrote 7 to {gain}, read back {default}"
        )
        link.write(1, "p_gain", 7, verify=False)  # acknowledged: no error without verify
        with pytest.raises(BusVerifyError):
            link.write_many(1, {"acceleration": 3, gain: 9})
        assert bus.table(1).get_role("acceleration") == 3


@pytest.mark.parametrize(
    ("family", "sdk_text"),
    [
        ("sts3215", "[TxRxResult] There is no status packet!"),
        ("xl430", "[TxRxResult] There is no status packet!"),
    ],
)
def test_a_missing_servo_names_port_servo_and_register(family, sdk_text):
    with VirtualBus(family, ids=(1, 3)) as bus, BusLink(bus.path, family) as link:
        with pytest.raises(BusTimeoutError) as caught:
            link.read(2, "goal_position")
        assert str(caught.value) == (
            f"servo 2 on {bus.path}: no reply reading goal_position (the SDK: {sdk_text})"
        )
        with pytest.raises(BusTimeoutError, match=f"servo 2 on {re.escape(bus.path)}: no reply "):
            link.sync_read("present_position", [1, 2, 3])
        with pytest.raises(BusTimeoutError, match="no reply pinging"):
            link.ping(2)


def test_model_mismatch_on_a_shared_protocol(reply_ms):
    with VirtualBus("xl330", ids=[ControlTable("xl430", 1)]) as bus:
        with (
            BusLink(bus.path, "xl330", timeout_ms=reply_ms) as link,
            pytest.raises(BusModelError) as caught,
        ):
            link.ping_all()
        assert "model number 1060, not the xl330's 1200" in str(caught.value)


def test_values_out_of_range_are_refused_before_sending(reply_ms):
    with VirtualBus("sts3215") as bus, BusLink(bus.path, "sts3215", timeout_ms=reply_ms) as link:
        before = bus.packets_received
        with pytest.raises(ValueError, match=r"p_coefficient must be in \[0, 254\], got 300"):
            link.write(1, "p_gain", 300)
        with pytest.raises(ValueError, match="present_position is read-only"):
            link.write(1, "present_position", 5)
        with pytest.raises(ValueError, match="goal_position"):
            link.sync_write("goal_position", {1: 10, 2: 40000})
        with pytest.raises(ValueError, match="acceleration"):
            link.write_many(1, {"p_gain": 5, "acceleration": 999})
        assert bus.packets_received == before
        assert bus.table(1).get("p_coefficient") == 32


def test_servo_refusals_and_hardware_alerts(reply_ms):
    with (
        VirtualBus("xl330") as bus,
        BusLink(bus.path, "xl330", raise_on_alert=True, timeout_ms=reply_ms) as link,
    ):
        link.torque(1, True)
        with pytest.raises(BusServoError) as caught:
            link.write(1, "id", 4)
        assert str(caught.value) == (
            f"servo 1 on {bus.path}: refused writing 4 to id: access error (read-only, or an "
            "EEPROM register while torque is on) (the SDK: [RxPacketError] Writing or Reading is "
            "not available to target address!)"
        )
        bus.table(1).set_role("error_status", bus.spec.error_bits["overheat"])
        with pytest.raises(
            BusAlertError, match=r"hardware alert \(overheat\) reading present_"
        ) as a:
            link.read(1, "present_position")  # the bits read from hardware_error_status
        assert a.value.bits == ["overheat"] and a.value.servo_id == 1
        link.raise_on_alert = False
        assert link.read(1, "hardware_error_status") == 4
        assert link.alerts[1] == 0x80
        link.torque(1, False)
        with pytest.raises(BusServoError, match=r"result fail \(torque stays off"):
            link.torque(1, True)
        link.reboot(1)
        assert link.read(1, "hardware_error_status") == 0 and link.alerts[1] == 0
        link.torque(1, True)


def test_sts_alerts_name_the_status_bits(reply_ms):
    with (
        VirtualBus("sts3215") as bus,
        BusLink(bus.path, "sts3215", raise_on_alert=True, timeout_ms=reply_ms) as link,
    ):
        bus.table(1).set_role("error_status", 0x24)
        with pytest.raises(BusAlertError) as caught:
            link.read(1, "goal_position")
        assert str(caught.value) == (
            f"servo 1 on {bus.path}: hardware alert (overheat, overload) reading goal_position "
            "(the SDK: [RxPacketError] Overheat error!)"
        )
        with pytest.raises(BusUnsupportedError, match="no REBOOT instruction"):
            link.reboot(1)


def test_corrupt_replies(reply_ms):
    with (
        VirtualBus("xl430") as bus,
        BusLink(bus.path, "xl430", retries=0, timeout_ms=reply_ms) as link,
    ):
        bus.corrupt_replies(1)
        with pytest.raises(BusCorruptError) as caught:
            link.read(1, "present_position")
        assert str(caught.value) == (
            f"servo 1 on {bus.path}: corrupt reply reading present_position (the SDK: "
            "[TxRxResult] Incorrect status packet!)"
        )
        bus.inject_garbage(b"\xff\xff\xfd\x00\x01\x07")
        assert link.read(1, "present_position") == 2048


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_a_lost_or_garbled_reply_is_sent_again_and_counted(family, reply_ms):
    with VirtualBus(family) as bus, BusLink(bus.path, family, timeout_ms=reply_ms) as link:
        bus.drop_replies(1)
        link.write(1, "p_gain", 20)  # the write is sent again (idempotent), then read back
        assert bus.table(1).get_role("p_gain") == 20 and link.retried == 1
        bus.corrupt_replies(1)
        assert link.read(1, "p_gain") == 20 and link.retried == 2
        link.retries = 1  # two windows (0.5 s and 0.8 s) are enough to show it
        bus.drop_replies(link.retries + 1)  # every attempt lost: an error, counted
        with pytest.raises(BusTimeoutError, match="no reply reading"):
            link.read(1, "p_gain")
        assert link.retried == 2 + link.retries


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_a_servo_quiet_for_half_a_second_is_waited_for(family):
    """A servo that answers nothing for 0.6 s, then everything it was sent (a virtual one whose
    thread a loaded host left waiting: the 4 tries' 50 ms windows and drains spanned 0.4 s, and
    a README walk's record failed): each try waits twice as long as the one before, and the
    last one's window takes the reply."""
    with VirtualBus(family) as bus, BusLink(bus.path, family) as link:
        held = threading.Event()

        def starve() -> None:
            with bus.lock:  # the servo's thread cannot serve the line meanwhile
                held.set()
                time.sleep(0.6)

        thread = threading.Thread(target=starve)
        thread.start()
        held.wait()
        link.write(1, "p_gain", 20)
        thread.join()
        assert bus.table(1).get_role("p_gain") == 20 and link.retried >= 2
        assert link._port.gripper_reply_ms == link.timeout_ms  # back to the first window


def test_opening_the_port():
    with pytest.raises(ValueError, match="unknown servo family 'mx28'; known: sts3215, xl330"):
        BusLink("/dev/null", "mx28")
    with pytest.raises(ValueError, match="cannot open a port at 12345 baud; it offers"):
        BusLink("/dev/null", "xl330", baudrate=12345)
    with pytest.raises(BusPortError, match="cannot open /nonexistent/tty at 57600 baud"):
        BusLink("/nonexistent/tty", "xl330", baudrate=57600)


@pytest.mark.parametrize(
    ("family", "factory", "other"),
    [("sts3215", 1_000_000, 115_200), ("xl330", 57_600, 1_000_000), ("xl430", 57_600, 1_000_000)],
)
def test_the_link_opens_at_the_factory_rate_unless_told(family, factory, other, reply_ms):
    """A servo fresh from its box answers a link opened with the defaults (the rates are the
    vendors': STS3215 1 Mbaud, XL330 / XL430 57600, as BusGripper's ``FACTORY_BAUD``); one set
    to another rate (as LeRobot sets its buses to 1 Mbaud) needs that rate given."""
    assert FACTORY_BAUD[family] == factory
    with VirtualBus(family) as bus, BusLink(bus.path, family, timeout_ms=reply_ms) as link:
        assert link.baudrate == factory
        assert link.ping(1) == bus.spec.model_number
    with VirtualBus(family, baudrate=other) as bus:
        with BusLink(bus.path, family) as link, pytest.raises(BusTimeoutError):
            link.ping(1)  # its bytes are noise at the factory rate
        with BusLink(bus.path, family, baudrate=other, timeout_ms=reply_ms) as link:
            assert link.ping(1) == bus.spec.model_number

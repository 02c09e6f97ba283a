"""The host's side of a servo bus, through the vendors' own SDKs.

:class:`BusLink` opens a port (a USB adapter such as the Feetech URT-1 or the ROBOTIS U2D2, or
a :class:`~gripper_env.hardware.bus.server.VirtualBus`) and reads and writes the servos'
registers by name, with the SDK of their family doing the talking: ``scservo_sdk``
(``PortHandler``, ``PacketHandler(0)``: little-endian STS) for the STS3215, ``dynamixel_sdk``
(``PortHandler``, ``PacketHandler(2.0)``) for the XL330 and XL430. Values are encoded and
decoded here from the tables (:mod:`~gripper_env.hardware.bus.tables`: sign-magnitude on the
STS, two's complement on the XL), and the SDKs move raw bytes only, so the scservo SDK's global
byte order (``SCS_SETEND``) cannot garble them.

Every failure raises a subclass of :class:`BusError` with one line naming the port, the servo,
the register and the SDK's own text (``getTxRxResult`` / ``getRxPacketError``), for example::

    servo 1 on /dev/pts/5: no reply reading goal_position (the SDK: [TxRxResult] There is no
    status packet!)

A value outside its field's range raises ``ValueError`` before anything is sent.

A hardware alert in a reply (the STS's status bits, the Dynamixel's alert bit) does not fail the
instruction it answers: it is recorded in :attr:`BusLink.alerts`, and raised as
:class:`BusAlertError` only with ``raise_on_alert=True``. Dynamixel status return level below 2
means writes get no reply: keep it at its factory 2 with this link.

The link is not thread-safe: one caller at a time.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import dynamixel_sdk
import scservo_sdk
import serial

from gripper_env.hardware.bus.dynamixel import ERRBIT_ALERT, ERROR_TEXT
from gripper_env.hardware.bus.tables import Field, get_spec

__all__ = [
    "BusAlertError",
    "BusCommError",
    "BusCorruptError",
    "BusError",
    "BusLink",
    "BusModelError",
    "BusPortError",
    "BusServoError",
    "BusTimeoutError",
    "BusUnsupportedError",
    "BusVerifyError",
]


class BusError(RuntimeError):
    """A bus transaction failed (the message names the port, servo, register and cause)."""


class BusPortError(BusError):
    """The port cannot be opened."""


class BusCommError(BusError):
    """The SDK could not send or receive (port busy, transmit failure...)."""


class BusTimeoutError(BusCommError):
    """No reply from the servo (missing, unpowered, wrong ID or baud rate)."""


class BusCorruptError(BusCommError):
    """A reply came but was garbled (checksum/CRC, truncated)."""


class BusServoError(BusError):
    """The servo answered but refused the instruction (a Dynamixel error number)."""


class BusAlertError(BusError):
    """The servo reports a hardware alert (with ``raise_on_alert=True``)."""


class BusVerifyError(BusError):
    """A written value did not read back."""


class BusModelError(BusError):
    """A servo answered with another model number than its family's."""


class BusUnsupportedError(BusError):
    """The family has no such instruction."""


class BusLink:
    """The host's session with the servos of one family on one port.

    Parameters
    ----------
    port : str
        Serial port (``/dev/ttyUSB0``, ``COM3``, a virtual bus's ``/dev/pts/N``).
    family : str
        ``"sts3215"``, ``"xl330"`` or ``"xl430"``.
    baudrate : int, optional
        Baud rate the port opens at; default the family's factory rate
        (:attr:`~gripper_env.hardware.bus.tables.TableSpec.factory_baudrate`: the STS3215's
        1 Mbaud, the XLs' 57600). A bus that LeRobot set up runs at 1 Mbaud: pass it.
    ids : iterable of int
        The servos' IDs: the default of :meth:`sync_read` and :meth:`ping_all`.
    raise_on_alert : bool
        Raise :class:`BusAlertError` when a reply carries a hardware alert (else only record it
        in :attr:`alerts`).

    Attributes
    ----------
    spec : TableSpec
    alerts : dict of int to int
        Per servo, the hardware-alert part of its last reply's error byte (STS: the status bits;
        Dynamixel: 0x80), 0 when clear.

    Raises
    ------
    ValueError
        Unknown family (naming the known ones) or a baud rate the SDK does not offer.
    BusPortError
        The port cannot be opened.
    """

    def __init__(
        self,
        port: str,
        family: str,
        baudrate: int | None = None,
        ids: Iterable[int] = (1,),
        *,
        raise_on_alert: bool = False,
    ) -> None:
        self.spec = get_spec(family)
        self.port = str(port)
        self.baudrate = self.spec.factory_baudrate if baudrate is None else int(baudrate)
        self.ids = tuple(int(i) for i in ids)
        self.raise_on_alert = raise_on_alert
        self.alerts: dict[int, int] = {}
        self._feetech = self.spec.protocol == "feetech"
        sdk = scservo_sdk if self._feetech else dynamixel_sdk
        self._sdk = sdk
        self._ph = sdk.PacketHandler(0) if self._feetech else sdk.PacketHandler(2.0)
        self._port = sdk.PortHandler(self.port)
        if self._port.getCFlagBaud(self.baudrate) <= 0:
            vendor = "scservo" if self._feetech else "dynamixel"
            raise ValueError(
                f"the {vendor} SDK cannot open a port at {self.baudrate} baud; it offers "
                f"{_offered_bauds(self._port)}"
            )
        try:
            opened = self._port.setBaudRate(self.baudrate)
        except (serial.SerialException, OSError) as exc:
            raise BusPortError(f"cannot open {self.port} at {self.baudrate} baud: {exc}") from exc
        if not opened:
            raise BusPortError(f"cannot open {self.port} at {self.baudrate} baud")

    # ---- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (idempotent)."""
        if getattr(self._port, "is_open", False):
            self._port.closePort()

    def __enter__(self) -> BusLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"BusLink({self.port!r}, {self.spec.family!r}, baudrate={self.baudrate})"

    # ---- single servo ----------------------------------------------------------------------------

    def ping(self, servo_id: int) -> int:
        """The model number servo ``servo_id`` reports."""
        model, result, error = self._ph.ping(self._clear(), servo_id)
        self._check(result, error, servo_id, "pinging")
        if self._feetech and scservo_sdk.SCS_GETEND() != 0:  # another caller set big-endian
            model = self.read(servo_id, self.spec.role("model_number").name)
        return int(model)

    def ping_all(self, ids: Iterable[int] | None = None) -> dict[int, int]:
        """Ping each servo (default :attr:`ids`); their model numbers.

        Raises
        ------
        BusModelError
            If one is not a servo of the link's family.
        """
        models = {}
        for servo_id in self.ids if ids is None else ids:
            model = self.ping(servo_id)
            if model != self.spec.model_number:
                raise BusModelError(
                    f"servo {servo_id} on {self.port}: model number {model}, not the "
                    f"{self.spec.family}'s {self.spec.model_number}"
                )
            models[servo_id] = model
        return models

    def read(self, servo_id: int, name: str) -> int:
        """The decoded value of register ``name`` (a field or a role) of servo ``servo_id``."""
        f = self.spec.resolve(name)
        data, result, error = self._ph.readTxRx(self._clear(), servo_id, f.address, f.size)
        self._check(result, error, servo_id, f"reading {f.name}")
        if len(data) != f.size:
            raise BusCorruptError(
                f"servo {servo_id} on {self.port}: {len(data)} bytes reading {f.name} "
                f"({f.size} expected)"
            )
        return f.decode(bytes(data))

    def write(self, servo_id: int, name: str, value: int, verify: bool = True) -> None:
        """Write ``value`` to register ``name`` (a field or a role) of servo ``servo_id``; with
        ``verify``, read it back.

        Raises
        ------
        ValueError
            Read-only register, or ``value`` outside its range (nothing is sent).
        BusVerifyError
            The value read back differs.
        """
        f = self.spec.resolve(name)
        f.check(value)
        self._write(servo_id, f, int(value))
        if verify:
            self._verify(servo_id, f, int(value))

    def write_many(self, servo_id: int, values: Mapping[str, int], verify: bool = True) -> None:
        """Write several registers of one servo (all values are checked before the first is
        sent), each read back with ``verify``."""
        fields = [(self.spec.resolve(name), int(value)) for name, value in values.items()]
        for f, value in fields:
            f.check(value)
        for f, value in fields:
            self._write(servo_id, f, value)
        if verify:
            for f, value in fields:
                self._verify(servo_id, f, value)

    def torque(self, servo_id: int, on: bool) -> None:
        """Turn servo ``servo_id``'s torque on or off (read back)."""
        self.write(servo_id, self.spec.role("torque_enable").name, 1 if on else 0)

    def reboot(self, servo_id: int) -> None:
        """Reboot a Dynamixel (clears a hardware error; torque comes back off).

        Raises
        ------
        BusUnsupportedError
            On the STS3215, which has no REBOOT instruction (switch its power off and on).
        """
        if self._feetech:
            raise BusUnsupportedError(
                f"servo {servo_id} on {self.port}: the {self.spec.family} has no REBOOT "
                "instruction; power-cycle it"
            )
        result, error = self._ph.reboot(self._clear(), servo_id)
        self._check(result, error, servo_id, "rebooting")

    # ---- several servos --------------------------------------------------------------------------

    def sync_read(self, name: str, ids: Iterable[int] | None = None) -> dict[int, int]:
        """Register ``name`` of several servos (default :attr:`ids`) in one SYNC READ.

        The SDKs keep no error byte of a sync read: hardware alerts are not seen here.
        """
        f = self.spec.resolve(name)
        ids = list(dict.fromkeys(self.ids if ids is None else ids))
        group = self._sdk.GroupSyncRead(self._clear(), self._ph, f.address, f.size)
        for servo_id in ids:
            group.addParam(servo_id)
        result = group.txRxPacket()
        if result != self._sdk.COMM_SUCCESS:
            got = getattr(group, "data_dict", {})
            culprit = next((i for i in ids if len(got.get(i) or ()) < f.size), ids[0])
            self._check(result, 0, culprit, f"sync reading {f.name} (IDs {ids})")
        values = {}
        for servo_id in ids:
            data = bytes(group.getData(servo_id, f.address + k, 1) for k in range(f.size))
            values[servo_id] = f.decode(data)
        return values

    def sync_write(self, name: str, values: Mapping[int, int], verify: bool = False) -> None:
        """Write register ``name`` of several servos in one SYNC WRITE (no reply); with
        ``verify``, read them back in a sync read."""
        f = self.spec.resolve(name)
        for value in values.values():
            f.check(value)
        group = self._sdk.GroupSyncWrite(self._clear(), self._ph, f.address, f.size)
        for servo_id, value in values.items():
            group.addParam(servo_id, list(f.encode(int(value))))
        result = group.txPacket()
        if result != self._sdk.COMM_SUCCESS:
            self._check(result, 0, min(values), f"sync writing {f.name} (IDs {list(values)})")
        if verify:
            got = self.sync_read(f.name, values)
            for servo_id, value in values.items():
                if got[servo_id] != int(value):
                    raise BusVerifyError(
                        f"servo {servo_id} on {self.port}: sync wrote {value} to {f.name}, "
                        f"read back {got[servo_id]}"
                    )

    # ---- internals -------------------------------------------------------------------------------

    def _clear(self) -> Any:
        """The port handler, its input emptied (the scservo SDK leaves stale bytes in it)."""
        ser = getattr(self._port, "ser", None)
        if ser is not None and self._port.is_open:
            ser.reset_input_buffer()
        return self._port

    def _write(self, servo_id: int, f: Field, value: int) -> None:
        data = list(f.encode(value))
        result, error = self._ph.writeTxRx(self._clear(), servo_id, f.address, f.size, data)
        self._check(result, error, servo_id, f"writing {value} to {f.name}")

    def _verify(self, servo_id: int, f: Field, value: int) -> None:
        got = self.read(servo_id, f.name)
        if got != value:
            raise BusVerifyError(
                f"servo {servo_id} on {self.port}: wrote {value} to {f.name}, read back {got}"
            )

    def _check(self, result: int, error: int, servo_id: int, action: str) -> None:
        """Raise the :class:`BusError` that ``result`` and ``error`` (the SDK's) call for."""
        where = f"servo {servo_id} on {self.port}"
        sdk = self._sdk
        if result != sdk.COMM_SUCCESS:
            kinds: dict[int, tuple[type[BusError], str]] = {
                sdk.COMM_RX_TIMEOUT: (BusTimeoutError, "no reply"),
                sdk.COMM_RX_CORRUPT: (BusCorruptError, "corrupt reply"),
            }
            kind, what = kinds.get(result, (BusCommError, "communication failed"))
            text = self._ph.getTxRxResult(result) or f"result {result}"
            raise kind(f"{where}: {what} {action} (the SDK: {text})")
        if self._feetech:
            number, alert = 0, error
        else:
            number, alert = error & ~ERRBIT_ALERT, error & ERRBIT_ALERT
        self.alerts[servo_id] = alert
        if number:
            note = f"; hardware alert {self._alert_text(alert)}" if alert else ""
            raise BusServoError(
                f"{where}: refused {action}: {ERROR_TEXT.get(number, f'error {number}')}"
                f"{_hint(number, action)}{note} (the SDK: {self._ph.getRxPacketError(number)})"
            )
        if alert and self.raise_on_alert:
            raise BusAlertError(
                f"{where}: hardware alert {self._alert_text(alert)} {action} "
                f"(the SDK: {self._ph.getRxPacketError(error)})"
            )

    def _alert_text(self, alert: int) -> str:
        if not self._feetech:
            return "(read hardware_error_status)"
        names = [name for name, bit in self.spec.error_bits.items() if alert & bit]
        return "(" + ", ".join(names or [f"status 0x{alert:02x}"]) + ")"


def _hint(number: int, action: str) -> str:
    if number == 7 and action.startswith("writing"):
        return " (read-only, or an EEPROM register while torque is on)"
    if number == 1 and "torque_enable" in action:
        return " (torque stays off after a hardware error until a reboot)"
    return ""


def _offered_bauds(port: Any) -> list[int]:
    """The baud rates the SDK's port handler accepts."""
    candidates = [4800 * 2**k for k in range(4)] + [14400, 57600, 115200, 128000, 230400]
    candidates += [250_000, 460_800, 500_000, 576_000, 921_600, 1_000_000, 1_152_000]
    candidates += [2_000_000, 2_500_000, 3_000_000, 3_500_000, 4_000_000]
    return sorted(b for b in set(candidates) if port.getCFlagBaud(b) > 0)

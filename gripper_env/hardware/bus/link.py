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

A real link loses replies: reads, writes and pings are sent again on a lost or garbled reply,
at most :attr:`BusLink.retries` times (a write is idempotent: the same value again), and
:attr:`BusLink.retried` counts the retries. A refusal by the servo is not retried. A port that
vanishes (the USB adapter unplugged, a virtual bus stopped: ``OSError``, ``termios.error`` or
pyserial's ``SerialException`` from the SDK) raises :class:`BusPortLostError` at once.

On a shared bus, :meth:`BusLink.scan` finds the servos with one broadcast PING (read-only;
every servo answers in ID order) and :meth:`BusLink.restrict` confines the link to one ID:
every later instruction to another ID is refused before it is sent (ValueError).

A hardware alert in a reply (the STS's status bits, the Dynamixel's alert bit) does not fail the
instruction it answers: it is recorded in :attr:`BusLink.alerts`, and raised as
:class:`BusAlertError` only with ``raise_on_alert=True`` (naming the bits: a Dynamixel's are
read from its ``hardware_error_status``). Dynamixel status return level below 2 means writes get
no reply: keep it at its factory 2 with this link.

Every SDK call is one transaction for :mod:`~gripper_env.hardware.bus.interrupts`: under
:func:`~gripper_env.hardware.bus.interrupts.handle_signals` a Ctrl-C or SIGTERM is raised when
the transaction ends, never inside it. Before each, the SDK's busy flag is cleared and its input
emptied: a transaction cut short elsewhere (a ``KeyboardInterrupt`` outside that block) leaves
both behind.

The link is not thread-safe: one caller at a time.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

import dynamixel_sdk
import scservo_sdk
import serial

from gripper_env.hardware.bus import feetech
from gripper_env.hardware.bus.dynamixel import ERRBIT_ALERT, ERROR_TEXT
from gripper_env.hardware.bus.interrupts import transaction
from gripper_env.hardware.bus.tables import Field, get_spec

try:  # POSIX: pyserial's reset_input_buffer raises termios.error on a vanished pty
    import termios

    _PORT_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover - Windows
    _PORT_ERRORS = (OSError,)

T = TypeVar("T")

__all__ = [
    "BusAlertError",
    "BusCommError",
    "BusCorruptError",
    "BusError",
    "BusLink",
    "BusModelError",
    "BusPortError",
    "BusPortLostError",
    "BusServoError",
    "BusTimeoutError",
    "BusUnsupportedError",
    "BusVerifyError",
]


class BusError(RuntimeError):
    """A bus transaction failed (the message names the port, servo, register and cause)."""


class BusPortError(BusError):
    """The port cannot be opened."""


class BusPortLostError(BusPortError):
    """The port went away during the session (adapter unplugged, virtual bus stopped)."""


class BusCommError(BusError):
    """The SDK could not send or receive (port busy, transmit failure...)."""


class BusTimeoutError(BusCommError):
    """No reply from the servo (missing, unpowered, wrong ID or baud rate)."""


class BusCorruptError(BusCommError):
    """A reply came but was garbled (checksum/CRC, truncated)."""


class BusServoError(BusError):
    """The servo answered but refused the instruction (a Dynamixel error number)."""


class BusAlertError(BusError):
    """The servo reports a hardware alert (with ``raise_on_alert=True``).

    Attributes
    ----------
    servo_id : int
    bits : list of str
        The error bits by name (``"overload"``...).
    """

    def __init__(self, message: str, servo_id: int = -1, bits: Iterable[str] = ()) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.bits = list(bits)


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
    retries : int
        How many times a read, write or ping is sent again after a lost or garbled reply.
    timeout_ms : float
        How long a reply is waited for beyond its transmission time (ms). Both SDKs wait twice
        a USB adapter's 16 ms latency timer and 2 ms; LeRobot found the scservo SDK's wait
        too short for its servos and waits 50 ms (its ``patch_setPacketTimeout``), as here.

    Attributes
    ----------
    spec : TableSpec
    alerts : dict of int to int
        Per servo, the hardware-alert part of its last reply's error byte (STS: the status bits;
        Dynamixel: 0x80), 0 when clear.
    retried : int
        Transactions sent again after a lost or garbled reply, over the session.
    allowed_ids : frozenset of int or None
        The only IDs instructions may go to (:meth:`restrict`); None: any.

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
        retries: int = 3,
        timeout_ms: float = 50.0,
    ) -> None:
        self.spec = get_spec(family)
        self.port = str(port)
        self.baudrate = self.spec.factory_baudrate if baudrate is None else int(baudrate)
        self.ids = tuple(int(i) for i in ids)
        self.raise_on_alert = raise_on_alert
        if not 0 <= retries <= 20:
            raise ValueError(f"retries must be 0..20, got {retries}")
        self.retries = int(retries)
        self.retried = 0
        self.allowed_ids: frozenset[int] | None = None
        self.alerts: dict[int, int] = {}
        self._feetech = self.spec.protocol == "feetech"
        sdk = scservo_sdk if self._feetech else dynamixel_sdk
        self._sdk = sdk
        self._ph = sdk.PacketHandler(0) if self._feetech else sdk.PacketHandler(2.0)
        self._port = sdk.PortHandler(self.port)
        self.timeout_ms = float(timeout_ms)
        _set_reply_timeout(self._port, self.timeout_ms)
        if self._port.getCFlagBaud(self.baudrate) <= 0:
            vendor = "scservo" if self._feetech else "dynamixel"
            raise ValueError(
                f"the {vendor} SDK cannot open a port at {self.baudrate} baud; it offers "
                f"{_offered_bauds(self._port)}"
            )
        try:
            opened = self._port.setBaudRate(self.baudrate)
        except (serial.SerialException, *_PORT_ERRORS) as exc:
            raise BusPortError(f"cannot open {self.port} at {self.baudrate} baud: {exc}") from exc
        if not opened:
            raise BusPortError(f"cannot open {self.port} at {self.baudrate} baud")

    # ---- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (idempotent; a port already gone is closed quietly)."""
        if getattr(self._port, "is_open", False):
            try:
                self._port.closePort()
            except (serial.SerialException, *_PORT_ERRORS):
                self._port.is_open = False

    def restrict(self, servo_id: int | None) -> None:
        """Allow instructions to ``servo_id`` only (``None``: to any again)."""
        self.allowed_ids = None if servo_id is None else frozenset({int(servo_id)})

    def __enter__(self) -> BusLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"BusLink({self.port!r}, {self.spec.family!r}, baudrate={self.baudrate})"

    # ---- single servo ----------------------------------------------------------------------------

    def ping(self, servo_id: int, retries: int | None = None) -> int:
        """The model number servo ``servo_id`` reports."""
        self._allowed(servo_id)

        def once() -> int:
            model, result, error = self._sdk_call(self._ph.ping, servo_id)
            self._check(result, error, servo_id, "pinging")
            return int(model)

        model = self._retrying(once, retries)
        if self._feetech and scservo_sdk.SCS_GETEND() != 0:  # another caller set big-endian
            model = self.read(servo_id, self.spec.role("model_number").name)
        return int(model)

    def scan(self) -> dict[int, int | None]:
        """The servos that answer one broadcast PING (read-only): ID -> model number (a
        Dynamixel's reply carries it; an STS's does not: None).

        Waits for every ID's reply slot (LeRobot's window: ``6 * 252`` bytes of transmission
        plus 3 ms per ID and 16 ms, about 0.8 s at 1 Mbaud).

        Raises
        ------
        BusPortLostError
            The port is gone.
        """
        if self._feetech:
            return dict.fromkeys(self._scan_feetech())
        found, _ = self._sdk_call(self._ph.broadcastPing)  # what came whole, even if some did not
        return {int(i): int(v[0]) for i, v in sorted(found.items())}

    def _scan_feetech(self) -> list[int]:
        """Broadcast PING on the SCS/STS protocol: the IDs of the whole status packets that come
        back within the window (the scservo SDK has no broadcast ping; this is LeRobot's)."""
        tx = [0] * 6
        tx[scservo_sdk.PKT_ID] = scservo_sdk.BROADCAST_ID
        tx[scservo_sdk.PKT_LENGTH] = 2
        tx[scservo_sdk.PKT_INSTRUCTION] = scservo_sdk.INST_PING
        byte_ms = 10_000.0 / self.baudrate
        window_s = (6 * feetech.MAX_ID * byte_ms + 3.0 * feetech.MAX_ID + 16.0) / 1e3
        parser = feetech.Parser()
        found: set[int] = set()

        def run(port: Any) -> None:
            result = self._ph.txPacket(port, tx)
            port.is_using = False
            if result != scservo_sdk.COMM_SUCCESS:
                self._check(result, 0, scservo_sdk.BROADCAST_ID, "broadcast pinging")
            end = time.monotonic() + window_s
            while time.monotonic() < end:
                data = port.readPort(4096)
                if data:
                    found.update(p.id for p in parser.feed(bytes(data)))
                else:
                    time.sleep(0.001)

        self._sdk_call(run)
        return sorted(found)

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

    def read(self, servo_id: int, name: str, retries: int | None = None) -> int:
        """The decoded value of register ``name`` (a field or a role) of servo ``servo_id``
        (sent again up to ``retries`` times on a lost reply; default :attr:`retries`)."""
        f = self.spec.resolve(name)
        self._allowed(servo_id)

        def once() -> int:
            data, result, error = self._sdk_call(self._ph.readTxRx, servo_id, f.address, f.size)
            self._check(result, error, servo_id, f"reading {f.name}")
            if len(data) != f.size:
                raise BusCorruptError(
                    f"servo {servo_id} on {self.port}: {len(data)} bytes reading {f.name} "
                    f"({f.size} expected)"
                )
            return f.decode(bytes(data))

        return self._retrying(once, retries)

    def write(
        self,
        servo_id: int,
        name: str,
        value: int,
        verify: bool = True,
        retries: int | None = None,
    ) -> None:
        """Write ``value`` to register ``name`` (a field or a role) of servo ``servo_id``; with
        ``verify``, read it back.

        Raises
        ------
        ValueError
            Read-only register, ``value`` outside its range, or a servo the link is restricted
            from (nothing is sent).
        BusVerifyError
            The value read back differs.
        """
        f = self.spec.resolve(name)
        f.check(value)
        self._allowed(servo_id)
        self._write(servo_id, f, int(value), retries)
        if verify:
            self._verify(servo_id, f, int(value))

    def write_block(self, servo_id: int, values: Mapping[str, int], verify: bool = True) -> None:
        """Write adjacent registers of one servo in one WRITE instruction (an STS saves its
        EEPROM once per instruction), each read back with ``verify``.

        Raises
        ------
        ValueError
            The registers are not adjacent, a value is out of range, or the servo is not
            allowed (nothing is sent).
        """
        fields = sorted(
            ((self.spec.resolve(n), int(v)) for n, v in values.items()),
            key=lambda fv: fv[0].address,
        )
        for (a, _), (b, _) in itertools.pairwise(fields):
            if a.end != b.address:
                raise ValueError(f"{a.name} and {b.name} are not adjacent registers")
        for f, value in fields:
            f.check(value)
        self._allowed(servo_id)
        data = b"".join(f.encode(value) for f, value in fields)
        first = fields[0][0]
        names = "+".join(f.name for f, _ in fields)

        def once() -> None:
            result, error = self._sdk_call(
                self._ph.writeTxRx, servo_id, first.address, len(data), list(data)
            )
            self._check(result, error, servo_id, f"writing {names}")

        self._retrying(once, None)
        if verify:
            for f, value in fields:
                self._verify(servo_id, f, value)

    def write_many(self, servo_id: int, values: Mapping[str, int], verify: bool = True) -> None:
        """Write several registers of one servo (all values are checked before the first is
        sent), each read back with ``verify``."""
        fields = [(self.spec.resolve(name), int(value)) for name, value in values.items()]
        for f, value in fields:
            f.check(value)
        self._allowed(servo_id)
        for f, value in fields:
            self._write(servo_id, f, value, None)
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
        self._allowed(servo_id)
        result, error = self._sdk_call(self._ph.reboot, servo_id)
        self._check(result, error, servo_id, "rebooting")

    # ---- several servos --------------------------------------------------------------------------

    def sync_read(self, name: str, ids: Iterable[int] | None = None) -> dict[int, int]:
        """Register ``name`` of several servos (default :attr:`ids`) in one SYNC READ.

        The SDKs keep no error byte of a sync read: hardware alerts are not seen here.
        """
        f = self.spec.resolve(name)
        ids = list(dict.fromkeys(self.ids if ids is None else ids))
        for servo_id in ids:
            self._allowed(servo_id)
        group = self._sdk.GroupSyncRead(self._port, self._ph, f.address, f.size)
        for servo_id in ids:
            group.addParam(servo_id)
        result = self._sdk_call(group.txRxPacket, with_port=False)
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
        for servo_id in values:
            self._allowed(servo_id)
        group = self._sdk.GroupSyncWrite(self._port, self._ph, f.address, f.size)
        for servo_id, value in values.items():
            group.addParam(servo_id, list(f.encode(int(value))))
        result = self._sdk_call(group.txPacket, with_port=False)
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
        """The port handler, ready for a transaction: its busy flag cleared (a transaction cut
        short by an exception leaves it set) and its input emptied (the scservo SDK leaves
        stale bytes in it)."""
        self._port.is_using = False
        ser = getattr(self._port, "ser", None)
        if ser is not None and self._port.is_open:
            ser.reset_input_buffer()
        return self._port

    def _sdk_call(self, fn: Callable[..., T], *args: Any, with_port: bool = True) -> T:
        """``fn(port, *args)`` (``fn(*args)`` without ``with_port``: a group's call) as one
        transaction: the port readied first, a vanished port raised as
        :class:`BusPortLostError`."""
        try:
            with transaction():
                port = self._clear()
                return fn(port, *args) if with_port else fn(*args)
        except (serial.SerialException, *_PORT_ERRORS) as exc:
            raise BusPortLostError(
                f"the port {self.port} is gone (the adapter unplugged, or the virtual servo "
                f"stopped): {_os_text(exc)}"
            ) from None
        except IndexError:
            # the scservo SDK indexes a status packet it took whole before checking its
            # length: a short reply (a busy line, another caller's bytes) is a garbled one
            name = getattr(fn, "__name__", "a transaction")
            raise BusCorruptError(f"a short status packet on {self.port} ({name})") from None

    #: The reply window doubles with each attempt after a lost reply, up to this (ms): a servo
    #: that went quiet for a moment (a virtual one on a loaded host went silent for more than
    #: the 0.4 s that four 50 ms windows and their drains spanned) answers a later, longer
    #: window; one that is gone is reported after about 1 s instead of 0.4 s.
    MAX_REPLY_MS = 800.0

    def _retrying(self, once: Callable[[], T], retries: int | None) -> T:
        """``once()``, again after a lost or garbled reply, at most ``retries`` more times, each
        time waiting twice as long for the reply (up to :attr:`MAX_REPLY_MS`); after each such
        reply the line is drained (:meth:`_drain`), and after a success that took more than one
        try (the earlier tries may be answered late). A late reply to an earlier try answers
        the same instruction, so it may answer a later try."""
        n = self.retries if retries is None else retries
        try:
            for attempt in range(n + 1):
                _reply_window(self._port, min(self.timeout_ms * 2**attempt, self.MAX_REPLY_MS))
                try:
                    result = once()
                except BusCommError:
                    self._drain()
                    if attempt == n:
                        raise
                    self.retried += 1
                    continue
                if attempt:  # the earlier tries may be answered yet: not the next one's reply
                    self._drain()
                return result
        finally:
            _reply_window(self._port, self.timeout_ms)
        raise AssertionError("unreachable")

    #: After a lost or garbled reply, how long the line is left to settle before its input is
    #: discarded (s): a reply that comes after the SDK gave up on it must not be taken for the
    #: reply to the next instruction (the SDKs match a status packet by the servo's ID only).
    DRAIN_S = 0.05

    def _drain(self) -> None:
        time.sleep(self.DRAIN_S)
        try:
            with transaction():
                self._clear()
        except (serial.SerialException, *_PORT_ERRORS) as exc:
            raise BusPortLostError(
                f"the port {self.port} is gone (the adapter unplugged, or the virtual servo "
                f"stopped): {_os_text(exc)}"
            ) from None

    def _allowed(self, servo_id: int) -> None:
        if self.allowed_ids is not None and servo_id not in self.allowed_ids:
            only = ", ".join(map(str, sorted(self.allowed_ids)))
            raise ValueError(
                f"refusing to address servo {servo_id} on {self.port}: this session talks to "
                f"servo {only} only"
            )

    def _write(self, servo_id: int, f: Field, value: int, retries: int | None) -> None:
        data = list(f.encode(value))

        def once() -> None:
            result, error = self._sdk_call(self._ph.writeTxRx, servo_id, f.address, f.size, data)
            self._check(result, error, servo_id, f"writing {value} to {f.name}")

        self._retrying(once, retries)

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
            bits = self._alert_bits(servo_id, alert)
            names = "(" + ", ".join(bits or ["unnamed"]) + ")"
            raise BusAlertError(
                f"{where}: hardware alert {names} {action} "
                f"(the SDK: {self._ph.getRxPacketError(error)})",
                servo_id,
                bits,
            )

    def _alert_bits(self, servo_id: int, alert: int) -> list[str]:
        """The alert's bits by name: an STS's are in the reply; a Dynamixel's are read from its
        hardware_error_status (a reply lost there leaves them unnamed)."""
        if not self._feetech:
            self.raise_on_alert = False
            try:
                alert = self.read(servo_id, self.spec.role("error_status").name)
            except BusCommError:
                return ["read hardware_error_status"]
            finally:
                self.raise_on_alert = True
        names = [name for name, bit in self.spec.error_bits.items() if alert & bit]
        return names or [f"status 0x{alert:02x}"]

    def _alert_text(self, alert: int) -> str:
        if not self._feetech:
            return "(read hardware_error_status)"
        names = [name for name, bit in self.spec.error_bits.items() if alert & bit]
        return "(" + ", ".join(names or [f"status 0x{alert:02x}"]) + ")"


def _set_reply_timeout(port: Any, timeout_ms: float) -> None:
    """Make the SDK's port handler wait ``timeout_ms`` for a reply beyond its transmission
    (:func:`_reply_window` changes it for the next transactions)."""
    if not 0.0 < timeout_ms <= 1000.0:
        raise ValueError(f"timeout_ms must be in (0, 1000] ms, got {timeout_ms}")
    _reply_window(port, timeout_ms)

    def set_packet_timeout(packet_length: int) -> None:
        port.packet_start_time = port.getCurrentTime()
        byte_ms = port.tx_time_per_byte
        port.packet_timeout = byte_ms * packet_length + byte_ms * 3.0 + port.gripper_reply_ms

    port.setPacketTimeout = set_packet_timeout


def _reply_window(port: Any, timeout_ms: float) -> None:
    """The reply wait (ms beyond the transmission) of the port's next transactions."""
    port.gripper_reply_ms = float(timeout_ms)


def _os_text(exc: BaseException) -> str:
    """``[Errno 5] Input/output error`` for an OSError or a termios.error alike."""
    args = exc.args
    if len(args) == 2 and isinstance(args[0], int) and isinstance(args[1], str):
        return f"[Errno {args[0]}] {args[1]}"
    return str(exc) or type(exc).__name__


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

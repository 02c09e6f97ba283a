"""Virtual bus servos on a pseudo-terminal: the host's SDK talks to them as to real ones.

:class:`VirtualBus` opens a pseudo-terminal (as :mod:`gripper_env.hardware.virtual` does for
the Arduino board) on which one or several servos of a protocol answer byte for byte: Feetech
SCS/STS (:mod:`~gripper_env.hardware.bus.feetech`) or Dynamixel Protocol 2.0
(:mod:`~gripper_env.hardware.bus.dynamixel`). Each servo is a
:class:`~gripper_env.hardware.bus.control_table.ControlTable` and, optionally, a
:class:`~gripper_env.hardware.bus.physics.Physics` that moves it; before answering each
instruction packet the bus advances every servo's physics to the present device time,
``(time.monotonic() - start) * speed`` seconds (or what ``clock`` returns).

What the servos answer, as the real ones do:

* a status packet to each instruction addressed to them; none to a broadcast (but a broadcast
  PING, which every servo answers in ID order), none to SYNC WRITE / BULK WRITE; SYNC READ and
  BULK READ replies in the order of the requested IDs;
* the status return level: Dynamixel ``status_return_level`` (0: PING only, 1: PING and reads,
  2: all), STS ``response_status_level`` (0: PING and READ only, 1: all); the ID and the level
  a reply goes by are the servo's when the instruction came (a write to the ID is answered
  from the old ID);
* the baud rate: a servo hears and answers only when the line runs at the rate its
  ``baud_rate`` register selects (within 3 %, a UART's tolerance): the rate the host set on the
  pseudo-terminal (its termios speed, what pyserial and the SDKs set); at another rate its bytes
  are noise to the servo, as on a real bus (LeRobot's ``scan_port`` finds a servo at one rate);
* the return delay, ``return_delay_time`` x 2 us of device time before each reply (the
  Dynamixel's factory 250 is 0.5 ms, the STS's 0); the physics is advanced lazily while the bus
  idles (with the wall clock) and skips rests in closed form
  (:class:`~gripper_env.hardware.bus.unit.ServoUnit`), so a reply after minutes of idling is as
  prompt as any;
* the error byte: STS, the ``status`` register's bits; Dynamixel, the alert bit 7 while
  ``hardware_error_status`` is not 0, with the error number of a refused instruction (the
  table's checks: :class:`~gripper_env.hardware.bus.control_table.ControlTable`); torque
  cannot be turned on while in alert, until a REBOOT clears the error;
* an STS refuses a write silently (it has no error number for it): the status packet is the
  usual one, the register keeps its value;
* instructions a Dynamixel does not know get an instruction error (FAST SYNC READ and FAST
  BULK READ included: they go to the broadcast ID, so no reply); an STS ignores them, and its
  RESET restores the factory table but keeps the ID (an assumption: Feetech does not say).

Fault injection for tests: :meth:`VirtualBus.inject_garbage` (noise before the next reply),
:meth:`~VirtualBus.corrupt_replies` (a flipped checksum bit), :meth:`~VirtualBus.truncate_replies`,
:meth:`~VirtualBus.drop_replies` and :meth:`~VirtualBus.silence` (a servo that stops
answering).

Examples
--------
>>> with VirtualBus("sts3215", ids=(1, 2)) as bus:  # doctest: +SKIP
...     print(bus.path)
...     bus.table(1).set("status", 0x20)  # an overload the host will see in the error byte
/dev/pts/7
"""

from __future__ import annotations

import fcntl
import os
import select
import termios
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from gripper_env.hardware.bus import dynamixel as dxl
from gripper_env.hardware.bus import feetech as scs
from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.physics import MirrorPhysics, Physics
from gripper_env.hardware.bus.tables import get_spec
from gripper_env.hardware.pty import PtyDevice, PtyEndpoint, write_pending

__all__ = ["Physics", "VirtualBus"]

_INTERBYTE_TIMEOUT_S = 0.02  # a partial packet older than this is dropped (the servo's timeout)
_IDLE_ADVANCE_S = 0.05  # while no byte comes, the physics catches up this often (wall clock)
_BAUD_TOLERANCE = 0.03  # a UART samples correctly within about 3 % of its rate
_TCGETS2 = 0x802C542A  # ioctl: struct termios2 (44 bytes; speeds at 36 and 40), x86 and ARM
#: termios speed constants by rate, for the systems without TCGETS2
_TERMIOS_SPEEDS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (
        9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000,
        1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000,
    )
    if hasattr(termios, f"B{rate}")
}  # fmt: skip


def line_baud(fd: int) -> int:
    """The line rate (baud) a terminal is set to: its output speed (``TCGETS2``, which holds a
    custom rate such as 128000 or 76800 as pyserial sets it; the termios constant elsewhere);
    0 if unknown."""
    try:
        buf = bytearray(44)
        fcntl.ioctl(fd, _TCGETS2, buf)
        return int.from_bytes(buf[40:44], "little")
    except OSError:
        pass
    try:
        return _TERMIOS_SPEEDS.get(termios.tcgetattr(fd)[5], 0)
    except termios.error:
        return 0


@dataclass
class _Servo:
    table: ControlTable
    physics: Physics
    silent: bool = False


class VirtualBus(PtyDevice):
    """Virtual bus servos on a pseudo-terminal, served by a background thread.

    Parameters
    ----------
    family : str
        The servos' family (``"sts3215"``, ``"xl330"``, ``"xl430"``): the protocol of the bus
        and the table of the servos given by ID.
    ids : iterable of int or ControlTable
        The servos: an ID makes a servo of ``family`` with factory values; a
        :class:`ControlTable` (of a family with the same protocol) is used as it is.
    physics : Physics or mapping of int to Physics or None, optional
        What moves the servos: one object for a single servo, or one per ID (a servo without
        one mirrors its goal position, :class:`~gripper_env.hardware.bus.physics.MirrorPhysics`).
    speed : float
        Device time per wall-clock time (> 0).
    clock : callable, optional
        Device time (s) instead of ``speed`` x the wall time since :meth:`start` (for
        deterministic tests).
    return_delay : bool
        Wait each servo's return delay time before its reply.
    baudrate : int, optional
        Configure every servo's ``baud_rate`` register (and its flash) for this rate, as a
        setup tool would have (LeRobot sets its buses to 1 Mbaud); default the registers'
        values (the factory's: STS3215 1 Mbaud, XL330 / XL430 57600).

    Attributes
    ----------
    packets_received : int
        Instruction packets decoded (addressed to anyone).
    packets_to : collections.Counter of int
        Instruction packets by the ID they address: a packet to one ID counts for it, a SYNC or
        BULK instruction for each ID it lists, any other broadcast for the broadcast ID (254).
    replies_sent : int
    bytes_received, bytes_sent : int
    error : BaseException or None
        What stopped the thread (a physics that raised, for example); :meth:`stop` re-raises it.
    on_packet : callable or None
        Called in the bus thread with each instruction packet (its ``id``, ``instruction`` and
        ``params``) once the servos have acted on it and before any reply is sent: a test's
        observation point (a signal sent to the host at a given write, for example).
    """

    def __init__(
        self,
        family: str,
        ids: Iterable[int | ControlTable] = (1,),
        *,
        physics: Physics | Mapping[int, Physics | None] | None = None,
        speed: float = 1.0,
        clock: Callable[[], float] | None = None,
        return_delay: bool = True,
        baudrate: int | None = None,
    ) -> None:
        self.spec = get_spec(family)
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = float(speed)
        self._clock = clock
        self.return_delay = return_delay
        tables = [
            item if isinstance(item, ControlTable) else ControlTable(self.spec, item)
            for item in ids
        ]
        if not tables:
            raise ValueError("a bus needs at least one servo")
        for t in tables:
            if t.spec.protocol != self.spec.protocol:
                raise ValueError(
                    f"a {t.spec.family} ({t.spec.protocol}) cannot share a {self.spec.protocol} bus"
                )
        if physics is None or isinstance(physics, Mapping):
            chosen = dict(physics or {})
            unknown = set(chosen) - {t.servo_id for t in tables}
            if unknown:
                raise ValueError(f"physics for servos not on the bus: {sorted(unknown)}")
        elif len(tables) == 1:
            chosen = {tables[0].servo_id: physics}
        else:
            raise ValueError("several servos need one physics each: physics={id: physics, ...}")
        self._servos = [_Servo(t, chosen.get(t.servo_id) or MirrorPhysics()) for t in tables]
        if baudrate is not None:
            for t in tables:
                t.store(t.spec.role("baud_rate").name, t.spec.baud_index(int(baudrate)))
        self._line_baud = 0
        self.lock = threading.RLock()
        self._parser: scs.Parser | dxl.Parser = (
            scs.Parser() if self.spec.protocol == "feetech" else dxl.Parser()
        )
        self._pty = PtyEndpoint("virtual bus")
        self._t0 = 0.0
        self._out = bytearray()
        self._garbage = bytearray()
        self._corrupt = self._truncate = self._drop = 0
        self.packets_received = self.replies_sent = 0
        self.packets_to: Counter[int] = Counter()
        self.bytes_received = self.bytes_sent = 0
        self.on_packet: Callable[[scs.Packet | dxl.Packet], None] | None = None

    # ---- lifecycle -------------------------------------------------------------------------------

    def start(self) -> VirtualBus:
        """Open the pty and start the servos' thread; returns ``self``."""
        if self._pty.started:
            raise RuntimeError("the virtual bus was already started")
        self._t0 = time.monotonic()
        self._pty.start(self._loop, name="virtual-bus")
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread and close the pty (idempotent); re-raises what stopped the thread."""
        self._pty.stop(timeout_s)
        error, self._pty.error = self._pty.error, None
        if error is not None:
            raise RuntimeError(f"the virtual bus stopped: {error!r}") from error

    def __enter__(self) -> VirtualBus:
        return self if self._pty.started else self.start()

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.stop()
        else:  # do not hide the exception on its way out
            try:
                self.stop()
            except RuntimeError:
                pass

    # ---- the servos ------------------------------------------------------------------------------

    def device_time(self) -> float:
        """The servos' time (s)."""
        if self._clock is not None:
            return self._clock()
        return (time.monotonic() - self._t0) * self.speed

    @property
    def ids(self) -> list[int]:
        """The servos' present IDs (the host may change them), in the order given."""
        return [s.table.servo_id for s in self._servos]

    def table(self, servo_id: int) -> ControlTable:
        """The control table of the servo whose ID is ``servo_id``."""
        return self._servo(servo_id).table

    def physics(self, servo_id: int) -> Physics:
        """The physics of the servo whose ID is ``servo_id``."""
        return self._servo(servo_id).physics

    def power_cycle(self, servo_id: int | None = None) -> None:
        """Switch a servo (all by default) off and on: tables from flash, physics rebooted."""
        with self.lock:
            for s in self._servos:
                if servo_id is None or s.table.servo_id == servo_id:
                    with s.table.lock:
                        s.table.power_cycle()
                        s.physics.reboot(s.table)

    def _servo(self, servo_id: int) -> _Servo:
        for s in self._servos:
            if s.table.servo_id == servo_id:
                return s
        raise KeyError(f"no servo with ID {servo_id} on the bus (IDs: {self.ids})")

    # ---- fault injection -------------------------------------------------------------------------

    def inject_garbage(self, data: bytes) -> None:
        """Put ``data`` on the line just before the next reply (noise)."""
        with self.lock:
            self._garbage += data

    def corrupt_replies(self, n: int = 1) -> None:
        """Flip a bit of the checksum (CRC) of each of the next ``n`` replies."""
        with self.lock:
            self._corrupt += n

    def truncate_replies(self, n: int = 1) -> None:
        """Cut each of the next ``n`` replies to its first half."""
        with self.lock:
            self._truncate += n

    def drop_replies(self, n: int = 1) -> None:
        """Lose the next ``n`` replies (the servo acts on the instruction, its reply is lost)."""
        with self.lock:
            self._drop += n

    def silence(self, servo_id: int, silent: bool = True) -> None:
        """A servo stops (or resumes) listening and answering, as if unplugged."""
        with self.lock:
            self._servo(servo_id).silent = silent

    @property
    def garbage_bytes(self) -> int:
        """Bytes from the host the servos could not parse."""
        return self._parser.garbage_bytes

    @property
    def bad_packets(self) -> int:
        """Packets from the host dropped for their checksum (CRC)."""
        return self._parser.bad_packets

    # ---- the thread ------------------------------------------------------------------------------

    def _loop(self, master: int, wake: int) -> None:
        """Serve the host until stopped (the thread's body; see :class:`PtyEndpoint`)."""
        last_rx = time.monotonic()
        while not self._pty.stopping.is_set():
            timeout = 0.005 if self._parser.pending or self._out else _IDLE_ADVANCE_S
            readable, _, _ = select.select([master, wake], [], [], timeout)
            self._flush(master)
            if master not in readable:
                if self._parser.pending and time.monotonic() - last_rx > _INTERBYTE_TIMEOUT_S:
                    with self.lock:
                        self._parser.reset()
                elif self._clock is None:
                    self._advance()  # keep the physics near the wall clock while idle
                continue
            try:
                data = os.read(master, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # EIO: nobody holds the slave (cannot happen while we do)
                time.sleep(0.01)
                continue
            if not data:
                continue
            last_rx = time.monotonic()
            with self.lock:
                self.bytes_received += len(data)
                packets = self._parser.feed(data)
            for packet in packets:
                self._handle(master, packet)

    def _advance(self) -> None:
        """Run every servo's physics to the present device time."""
        with self.lock:
            now = self.device_time()
            for s in self._servos:
                with s.table.lock:
                    s.physics.advance(s.table, now)

    def _handle(self, master: int, packet: scs.Packet | dxl.Packet) -> None:
        slave = self._pty.slave
        line = line_baud(slave) if slave is not None else 0
        with self.lock:
            self.packets_received += 1
            self.packets_to.update(_addressed(packet))
            self._line_baud = line
            self._advance()
            if isinstance(packet, scs.Packet):
                replies = self._feetech(packet)
            else:
                replies = self._dynamixel(packet)
        if self.on_packet is not None:
            self.on_packet(packet)
        for servo, reply in replies:
            self._send(master, servo, reply)

    def _send(self, master: int, servo: _Servo, reply: bytes) -> None:
        if self.return_delay:
            delay_s = servo.table.get_role("return_delay") * 2e-6 / self.speed
            if delay_s > 0:
                time.sleep(delay_s)
        with self.lock:
            if self._drop:
                self._drop -= 1
                return
            if self._corrupt:
                self._corrupt -= 1
                reply = reply[:-1] + bytes([reply[-1] ^ 0x01])
            elif self._truncate:
                self._truncate -= 1
                reply = reply[: len(reply) // 2]
            self._out += self._garbage + reply
            self._garbage.clear()
            self.replies_sent += 1
        self._flush(master)

    def _flush(self, master: int) -> None:
        with self.lock:
            self.bytes_sent += write_pending(master, self._out)

    def _hears(self, s: _Servo) -> bool:
        """The servo listens and the line runs at its baud rate."""
        if s.silent:
            return False
        spec = s.table.spec
        try:
            rate = spec.baud(s.table.get_role("baud_rate"))
        except ValueError:
            return False
        return abs(self._line_baud - rate) <= _BAUD_TOLERANCE * rate

    def _targets(self, packet_id: int) -> list[_Servo]:
        """The servos an instruction to ``packet_id`` reaches, in ID order."""
        servos = [s for s in self._servos if self._hears(s)]
        if packet_id == dxl.BROADCAST_ID:  # the same ID on both protocols
            return sorted(servos, key=lambda s: s.table.servo_id)
        return [s for s in servos if s.table.servo_id == packet_id]

    def _listed(self, servo_id: int) -> _Servo | None:
        for s in self._servos:
            if self._hears(s) and s.table.servo_id == servo_id:
                return s
        return None

    @property
    def line_baud(self) -> int:
        """The line rate (baud) the host set, as the last packet found it (0: none yet)."""
        return self._line_baud

    # ---- Feetech SCS/STS -------------------------------------------------------------------------

    def _feetech(self, p: scs.Packet) -> list[tuple[_Servo, bytes]]:
        inst, params, broadcast = p.code, p.params, p.id == scs.BROADCAST_ID
        replies: list[tuple[_Servo, bytes]] = []
        before: dict[int, tuple[int, int]] = {}  # as the instruction found them: ID, level

        def status(s: _Servo, data: bytes = b"", *, read: bool = False) -> None:
            servo_id, level = before.get(id(s)) or _id_and_level(s.table)
            if read or level >= 1:
                error = s.table.get_role("error_status") & 0x7F  # the SDK rejects bit 7
                replies.append((s, scs.encode_status(servo_id, error, data)))

        if inst == scs.INST_SYNC_READ:
            if len(params) >= 2:
                address, length = params[0], params[1]
                for servo_id in params[2:]:
                    s = self._listed(servo_id)
                    if s is not None:
                        status(s, s.table.read(address, length), read=True)
            return replies
        if inst == scs.INST_SYNC_WRITE:
            if len(params) >= 2:
                address, length = params[0], params[1]
                chunks = params[2:]
                for k in range(0, len(chunks) - length, length + 1):
                    s = self._listed(chunks[k])
                    if s is not None:
                        s.table.write(address, chunks[k + 1 : k + 1 + length])
            return replies
        for s in self._targets(p.id):
            table = s.table
            before[id(s)] = _id_and_level(table)
            if inst == scs.INST_PING:
                status(s, read=True)
            elif inst == scs.INST_READ and len(params) == 2 and not broadcast:
                status(s, table.read(params[0], params[1]), read=True)
            elif inst == scs.INST_WRITE and len(params) >= 2:
                table.write(params[0], params[1:])  # a refusal leaves no trace in the reply
                if not broadcast:
                    status(s)
            elif inst == scs.INST_REG_WRITE and len(params) >= 2:
                table.reg_write(params[0], params[1:])
                if not broadcast:
                    status(s)
            elif inst == scs.INST_ACTION:
                table.action()
                if not broadcast:
                    status(s)
            elif inst == scs.INST_RESET:
                table.factory_reset(keep_id=True)
                s.physics.reboot(table)
                if not broadcast:
                    status(s)
        return replies

    # ---- Dynamixel Protocol 2.0 ------------------------------------------------------------------

    def _dynamixel(self, p: dxl.Packet) -> list[tuple[_Servo, bytes]]:
        inst, params, broadcast = p.instruction, p.params, p.id == dxl.BROADCAST_ID
        replies: list[tuple[_Servo, bytes]] = []
        before: dict[int, tuple[int, int]] = {}  # as the instruction found them: ID, level
        if inst == dxl.INST_STATUS:
            return replies  # another servo's reply on the line

        def status(s: _Servo, error: int = 0, data: bytes = b"", *, level: int = 2) -> None:
            servo_id, return_level = before.get(id(s)) or _id_and_level(s.table)
            if return_level >= level:
                alert = dxl.ERRBIT_ALERT if s.table.get_role("error_status") else 0
                replies.append((s, dxl.encode_status(servo_id, alert | error, data)))

        def read(s: _Servo, address: int, length: int) -> None:
            error = s.table.check_read(address, length)
            status(s, error, b"" if error else s.table.read(address, length), level=1)

        if inst in (dxl.INST_SYNC_READ, dxl.INST_SYNC_WRITE):
            if len(params) < 4:
                return replies
            address, length = _u16(params, 0), _u16(params, 2)
            if inst == dxl.INST_SYNC_READ:
                for servo_id in params[4:]:
                    s = self._listed(servo_id)
                    if s is not None:
                        read(s, address, length)
            else:
                chunks = params[4:]
                for k in range(0, len(chunks) - length, length + 1):
                    s = self._listed(chunks[k])
                    if s is not None:
                        s.table.write(address, chunks[k + 1 : k + 1 + length])
            return replies
        if inst == dxl.INST_BULK_READ:
            for k in range(0, len(params) - 4, 5):
                s = self._listed(params[k])
                if s is not None:
                    read(s, _u16(params, k + 1), _u16(params, k + 3))
            return replies
        if inst == dxl.INST_BULK_WRITE:
            k = 0
            while k + 5 <= len(params):
                length = _u16(params, k + 3)
                s = self._listed(params[k])
                if s is not None:
                    s.table.write(_u16(params, k + 1), params[k + 5 : k + 5 + length])
                k += 5 + length
            return replies
        for s in self._targets(p.id):
            table = s.table
            before[id(s)] = _id_and_level(table)
            if inst == dxl.INST_PING:
                model = table.get_role("model_number").to_bytes(2, "little")
                status(s, 0, model + bytes([table.get("firmware_version")]), level=0)
            elif broadcast and inst in (dxl.INST_READ, dxl.INST_WRITE, dxl.INST_REG_WRITE):
                if inst != dxl.INST_READ and len(params) >= 3:
                    write = table.write if inst == dxl.INST_WRITE else table.reg_write
                    write(_u16(params, 0), params[2:])
            elif inst == dxl.INST_READ:
                if len(params) != 4:
                    status(s, dxl.ERR_DATA_LENGTH, level=1)
                else:
                    read(s, _u16(params, 0), _u16(params, 2))
            elif inst in (dxl.INST_WRITE, dxl.INST_REG_WRITE):
                if len(params) < 3:
                    status(s, dxl.ERR_DATA_LENGTH)
                else:
                    write = table.write if inst == dxl.INST_WRITE else table.reg_write
                    status(s, write(_u16(params, 0), params[2:]))
            elif inst == dxl.INST_ACTION:
                error = table.action()
                if not broadcast:
                    status(s, dxl.ERR_INSTRUCTION if error is None else error)
            elif inst == dxl.INST_REBOOT:
                table.reboot()
                s.physics.reboot(table)
                if not broadcast:
                    status(s)
            elif inst == dxl.INST_FACTORY_RESET:
                option = params[0] if params else 0xFF
                if option not in (0x01, 0x02, 0xFF):
                    if not broadcast:
                        status(s, dxl.ERR_DATA_RANGE)
                    continue
                if not (broadcast and option == 0xFF):  # refused since firmware 42
                    table.factory_reset(keep_id=option != 0xFF, keep_baud_rate=option == 0x02)
                    s.physics.reboot(table)
                if not broadcast:
                    status(s)
            elif inst == dxl.INST_CLEAR:
                if params != b"\x01\x44\x58\x4c\x22" or table.get_role("moving"):
                    error = dxl.ERR_RESULT_FAIL
                else:
                    error = 0  # positions stay within one turn here: nothing to clear
                if not broadcast:
                    status(s, error)
            elif not broadcast:
                status(s, dxl.ERR_INSTRUCTION)
        return replies


def _addressed(packet: scs.Packet | dxl.Packet) -> list[int]:
    """The IDs an instruction packet addresses (see :attr:`VirtualBus.packets_to`)."""
    params = packet.params
    if isinstance(packet, scs.Packet):
        if packet.code == scs.INST_SYNC_READ:
            return list(params[2:])
        if packet.code == scs.INST_SYNC_WRITE and len(params) >= 2:
            return list(params[2 :: params[1] + 1])
        return [packet.id]
    inst = packet.instruction
    if inst == dxl.INST_SYNC_READ:
        return list(params[4:])
    if inst == dxl.INST_SYNC_WRITE and len(params) >= 4:
        return list(params[4 :: _u16(params, 2) + 1])
    if inst == dxl.INST_BULK_READ:
        return list(params[0::5])
    if inst == dxl.INST_BULK_WRITE:
        ids, k = [], 0
        while k + 5 <= len(params):
            ids.append(params[k])
            k += 5 + _u16(params, k + 3)
        return ids
    return [packet.id]


def _id_and_level(table: ControlTable) -> tuple[int, int]:
    """A servo's ID and status return level: a reply goes out as the instruction found them
    (a write to the ID is answered from the old ID, as LeRobot's motor setup relies on)."""
    return table.servo_id, table.get_role("status_return_level")


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | data[offset + 1] << 8

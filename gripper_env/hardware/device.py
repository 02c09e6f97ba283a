"""The host's handle on the gripper board: :class:`GripperDevice`.

It opens a serial port (a path such as ``/dev/ttyACM0`` or ``/dev/pts/7``, or any pyserial URL),
waits for the board to boot (opening the port resets a real Mega: ``boot_wait_s`` = 2 s by
default; the virtual device boots instantly, pass 0), does the version handshake, configures
the board's PID, limits and calibration, switches modes, streams setpoints and collects the
batched telemetry into arrays. Used as a context manager it always leaves the device stopped in
the safe (open) position, whatever happened inside the block.

Every failure is a :class:`DeviceError` subclass that says what happened:

=====================  ============================================================================
:class:`DeviceTimeout`  no valid answer in time (a silent device)
:class:`LinkError`      answers arrived but were corrupted (CRC, COBS, truncated frames)
:class:`DeviceReset`    the board restarted (it lost the session: NO_SESSION, unsolicited INFO)
:class:`PortVanished`   the serial port disappeared (cable pulled)
:class:`DeviceRefused`  the board answered ERROR (``VersionMismatch`` for a protocol mismatch)
:class:`DeviceFault`    a fault latched on the board (watchdog, ESTOP, sensor, numeric)
=====================  ============================================================================

Examples
--------
>>> with GripperDevice("/dev/ttyACM0") as dev:  # doctest: +SKIP
...     dev.configure(PIDGains(1.0, 9.0, -0.001), calibration=load_calibration())
...     dev.set_setpoint(92.0)
...     dev.set_mode(Mode.CLOSED_LOOP)
...     block = dev.wait_telemetry(1.0)
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import serial
import serial.tools.list_ports

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.calibration import Calibration
from gripper_env.hardware.protocol import ErrorCode, Fault, Mode, SampleFlag
from gripper_env.pid import ANTI_WINDUP_MODES, PIDGains, PIDOptions

__all__ = [
    "BAUDRATE",
    "DeviceError",
    "DeviceFault",
    "DeviceRefused",
    "DeviceReset",
    "DeviceTimeout",
    "GripperDevice",
    "LinkError",
    "PortVanished",
    "TelemetryBlock",
    "VersionMismatch",
    "fault_names",
    "list_ports",
]

BAUDRATE = 1_000_000
ERROR_NAMES = {v: k for k, v in vars(ErrorCode).items() if not k.startswith("_")}
FAULT_BITS = {"WATCHDOG": Fault.WATCHDOG, "ESTOP": Fault.ESTOP, "NUMERIC": Fault.NUMERIC}
FAULT_BITS["SENSOR"] = Fault.SENSOR


def fault_names(bits: int) -> str:
    """``"WATCHDOG+ESTOP"`` for fault bits (``"none"`` for 0)."""
    names = [name for name, bit in FAULT_BITS.items() if bits & bit]
    return "+".join(names) or "none"


class DeviceError(Exception):
    """Base class of everything that can go wrong talking to the board."""


class DeviceTimeout(DeviceError, TimeoutError):
    """No valid answer arrived in time."""


class LinkError(DeviceError, proto.ProtocolError):
    """Frames arrived but failed their checks (CRC, COBS, length), so no valid answer came."""


class DeviceReset(DeviceError):
    """The board restarted and lost its session, mode and configuration."""


class PortVanished(DeviceError, ConnectionError):
    """The serial port went away (unplugged cable, closed pseudo-terminal)."""


class DeviceRefused(DeviceError):
    """The board answered a command with ERROR.

    Attributes
    ----------
    code : int
        :class:`~gripper_env.hardware.protocol.ErrorCode`.
    detail : int
        The code-specific detail (field index, fault bits, version...).
    """

    def __init__(self, message: str, code: int, detail: int) -> None:
        super().__init__(message)
        self.code = code
        self.detail = detail


class VersionMismatch(DeviceRefused):
    """The board speaks another protocol version."""


class DeviceFault(DeviceError):
    """A fault latched on the board: it made a safe stop (idle, jaw open).

    Attributes
    ----------
    faults : int
        The latched :class:`~gripper_env.hardware.protocol.Fault` bits.
    """

    def __init__(self, message: str, faults: int) -> None:
        super().__init__(message)
        self.faults = faults


def list_ports() -> list[tuple[str, str]]:
    """Serial ports that may be a gripper board: ``(device, description)``, Arduinos first."""
    ports = []
    for p in serial.tools.list_ports.comports():
        text = f"{p.description or ''} {p.manufacturer or ''}".strip()
        arduino = "arduino" in text.lower() or (p.vid == 0x2341)  # Arduino's USB vendor id
        ports.append((not arduino, p.device, text or "serial port"))
    return [(device, text) for _, device, text in sorted(ports)]


@dataclass
class TelemetryBlock:
    """Telemetry samples as arrays (one entry per sample).

    Attributes
    ----------
    t_us : ndarray of int64
        Device time (us, unwrapped: monotonic over the session).
    reference_deg, command_deg : ndarray
        Reference (or open-loop setpoint) and servo command (deg); NaN while the servo is off.
    adc : ndarray of int
        Potentiometer reading (counts).
    position_deg : ndarray
        Measured jaw angle (deg) from ``adc`` by the host's calibration (NaN without one).
    flags : ndarray of uint8
        :class:`~gripper_env.hardware.protocol.SampleFlag` bits.
    """

    t_us: np.ndarray
    reference_deg: np.ndarray
    command_deg: np.ndarray
    adc: np.ndarray
    position_deg: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return len(self.t_us)

    @property
    def mode(self) -> np.ndarray:
        """Device mode at each sample."""
        return self.flags & SampleFlag.MODE_MASK

    @classmethod
    def concatenate(cls, blocks: list[TelemetryBlock]) -> TelemetryBlock:
        blocks = [b for b in blocks if len(b)]
        if not blocks:
            return cls.empty()
        if len(blocks) == 1:
            return blocks[0]
        return cls(*(np.concatenate([getattr(b, f) for b in blocks]) for f in _BLOCK_FIELDS))

    @classmethod
    def empty(cls) -> TelemetryBlock:
        f, i = np.zeros(0), np.zeros(0, dtype=np.int64)
        return cls(i, f, f.copy(), i.copy(), f.copy(), np.zeros(0, dtype=np.uint8))


_BLOCK_FIELDS = ("t_us", "reference_deg", "command_deg", "adc", "position_deg", "flags")
_SAMPLE_DTYPE = np.dtype([("r", "<i2"), ("u", "<i2"), ("adc", "<u2"), ("flags", "u1")])


class GripperDevice:
    """A session with the gripper board over a serial port (see the module docstring).

    Parameters
    ----------
    port : str
        Serial device path or pyserial URL.
    calibration : Calibration, optional
        ADC-to-angle calibration: sent with :meth:`configure` and used for ``position_deg``.
    boot_wait_s : float
        Time to let the board boot after opening the port (s): 2 for a real Mega (opening
        resets it), 0 for the virtual device.
    timeout_s : float
        How long to wait for each answer (s).
    retries : int
        How many times a command whose answer did not come is sent again.
    baudrate : int
        Line rate (the firmware uses 1 000 000).
    open : bool
        Open and handshake now (default); otherwise call :meth:`open`.
    """

    def __init__(
        self,
        port: str,
        *,
        calibration: Calibration | None = None,
        boot_wait_s: float = 2.0,
        timeout_s: float = 0.5,
        retries: int = 2,
        baudrate: int = BAUDRATE,
        open: bool = True,
    ) -> None:
        self.port = port
        self.calibration = calibration
        self.boot_wait_s = boot_wait_s
        self.timeout_s = timeout_s
        self.retries = retries
        self.baudrate = baudrate
        self.info: proto.Info | None = None
        self.last_status: proto.Status | None = None
        self.faults = 0
        # Synced: the port's input is flushed before the handshake, so the first byte most likely
        # starts the answer to HELLO; bytes of a frame cut short glue to it and fail its CRC.
        # (Unsynced, the decoder threw away that first answer, and every open waited out one
        # timeout and sent HELLO again: found against the emulated board.)
        self.decoder = proto.FrameDecoder()
        self.samples_missing = 0
        self._serial: Any = None
        self._seq = 0
        self._session = False
        self._mode = Mode.IDLE
        self._blocks: list[TelemetryBlock] = []
        self._last_t_raw: int | None = None
        self._t_offset = 0
        self._next_t_us: int | None = None
        self._latest_t_us: int | None = None
        self._token = 0
        self._last_rx_wall = time.monotonic()
        if open:
            self.open()

    # ---- connection ----------------------------------------------------------------------------

    def open(self) -> proto.Info:
        """Open the port, let the board boot, and do the handshake; return its INFO."""
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=0.01, write_timeout=1.0
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise PortVanished(f"cannot open serial port {self.port!r}: {exc}") from None
        try:
            if self.boot_wait_s > 0:
                time.sleep(self.boot_wait_s)
            self._serial.reset_input_buffer()
            return self.handshake()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Close the port (without stopping the device: see :meth:`stop`)."""
        ser, self._serial = self._serial, None
        self._session = False
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError):
                pass

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def __enter__(self) -> GripperDevice:
        if self._serial is None:
            self.open()
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        try:
            self.safe_stop()
        finally:
            self.close()

    # ---- commands ------------------------------------------------------------------------------

    def handshake(self) -> proto.Info:
        """Send HELLO and check the board's protocol version; return its INFO."""
        self._write(b"\x00")  # end any partial frame the board may hold
        self._session = False
        self.decoder.reset_sequence()
        info = self._request(proto.Hello(), proto.Info)
        if info.protocol_version != proto.PROTOCOL_VERSION:
            raise VersionMismatch(
                f"device on {self.port} speaks protocol version {info.protocol_version}, this "
                f"host speaks {proto.PROTOCOL_VERSION}: update the firmware or the host",
                ErrorCode.VERSION_MISMATCH,
                info.protocol_version,
            )
        self.info = info
        self._session = True
        self._mode = Mode.IDLE
        self.faults = 0
        return info

    def configure(
        self,
        gains: PIDGains | None = None,
        options: PIDOptions | None = None,
        *,
        calibration: Calibration | None = None,
        jaw_deg: tuple[float, float] = (21.0, 92.0),
        decimation: int = 1,
        telemetry_batch: int = 10,
        servo_us: tuple[int, int] = (544, 2400),
    ) -> proto.Status:
        """Send the controller, calibration and telemetry settings (CONFIGURE).

        Parameters
        ----------
        gains : PIDGains, optional
            PID gains (zero gains if omitted: open-loop use).
        options : PIDOptions, optional
            Output limits (deg), anti-windup, kb, derivative input, sign.
        calibration : Calibration, optional
            Replaces the device's calibration (default: the one given at construction).
        jaw_deg : (float, float)
            Jaw range (deg) every command is clamped into; the upper end is the safe position.
        decimation : int
            One telemetry sample every ``decimation`` ticks (1 = 1 kHz).
        telemetry_batch : int
            Samples per telemetry frame (1..32).
        servo_us : (int, int)
            Servo pulse widths (us) at 0 and 180 deg.
        """
        gains = gains or PIDGains(0.0, 0.0, 0.0)
        options = options or PIDOptions()
        if calibration is not None:
            self.calibration = calibration
        if self.calibration is None:
            raise ValueError("configure needs a calibration (python -m rig.calibrate)")
        lo_counts, hi_counts = self.calibration.device_counts
        msg = proto.Configure(
            p=float(gains.P),
            i=float(gains.I),
            d=float(gains.D),
            n=float(gains.N),
            u_min=float(options.output_limits[0]),
            u_max=float(options.output_limits[1]),
            kb=float(options.kb),
            jaw_min=float(jaw_deg[0]),
            jaw_max=float(jaw_deg[1]),
            adc_at_lo=lo_counts,
            adc_at_hi=hi_counts,
            servo_us_at_0=int(servo_us[0]),
            servo_us_at_180=int(servo_us[1]),
            decimation=int(decimation),
            anti_windup=ANTI_WINDUP_MODES[options.anti_windup],
            sign=int(options.sign),
            d_on_meas=1 if options.derivative_on == "measurement" else 0,
            telemetry_batch=int(telemetry_batch),
        )
        return self._request(msg, proto.Status)

    def set_mode(self, mode: int) -> proto.Status:
        """Switch to IDLE (safe position, acknowledges faults), OPEN_LOOP or CLOSED_LOOP."""
        status = self._request(proto.SetMode(mode), proto.Status)
        self._mode = mode
        if mode == Mode.IDLE:
            self.faults = 0
        return status

    def set_setpoint(self, angle_deg: float) -> None:
        """Send the open-loop command or closed-loop reference (deg); no answer is awaited."""
        if not math.isfinite(angle_deg):
            raise ValueError(f"setpoint must be a finite angle, got {angle_deg}")
        self._send(proto.Setpoint(float(angle_deg)))

    def heartbeat(self) -> tuple[proto.Status, float]:
        """A HEARTBEAT round trip: return the STATUS and the round-trip time (s)."""
        self._token = (self._token + 1) & 0xFFFFFFFF
        t = time.perf_counter()
        status = self._request(proto.Heartbeat(self._token), proto.Status)
        return status, time.perf_counter() - t

    def send_heartbeat(self) -> None:
        """Feed the board's watchdog without waiting for the STATUS (collected by :meth:`poll`)."""
        self._token = (self._token + 1) & 0xFFFFFFFF
        self._send(proto.Heartbeat(self._token))

    def estop(self) -> None:
        """Emergency stop: honoured with or without a session; the fault stays latched."""
        self._send(proto.Estop())
        self._mode = Mode.IDLE

    def safe_stop(self) -> bool:
        """Best effort to leave the board idle in the safe position; never raises.

        SET_MODE(IDLE) moves the jaw to the safe (open) position and acknowledges faults; if it
        gets no answer, an ESTOP (honoured even without a session) does the same and latches.
        Returns True if the board confirmed.
        """
        if self._serial is None:
            return False
        try:
            if self._session:
                self.set_mode(Mode.IDLE)
                return True
        except DeviceError:
            pass
        try:
            self.estop()
            deadline = time.monotonic() + self.timeout_s
            while time.monotonic() < deadline:
                for msg in self._pump(0.02, strict=False):
                    if isinstance(msg, proto.Status) and msg.mode == Mode.IDLE:
                        return True
        except DeviceError:
            pass
        return False

    # ---- telemetry -----------------------------------------------------------------------------

    def poll(self, timeout_s: float = 0.0) -> list[proto.Message]:
        """Read what arrived (waiting up to ``timeout_s`` for the first byte).

        Telemetry goes to the buffer (:meth:`read_telemetry`); the other messages are returned.

        Raises
        ------
        DeviceFault
            A fault latched on the board while an active mode was requested.
        DeviceReset, PortVanished
        """
        return self._pump(timeout_s)

    def read_telemetry(self) -> TelemetryBlock:
        """Telemetry received since the last call, as arrays (the buffer is emptied)."""
        blocks, self._blocks = self._blocks, []
        return TelemetryBlock.concatenate(blocks)

    def wait_telemetry(
        self, duration_s: float, timeout_s: float | None = None, heartbeat_s: float = 0.1
    ) -> TelemetryBlock:
        """Collect ``duration_s`` of device time of telemetry, feeding the watchdog meanwhile.

        Parameters
        ----------
        duration_s : float
            Device time to collect (s).
        timeout_s : float, optional
            Wall time without telemetry before giving up (default :attr:`timeout_s`).
        heartbeat_s : float
            HEARTBEAT period in device time (s) while waiting; 0 sends none (the board's
            watchdog then fires after 500 ms in an active mode).

        Raises
        ------
        DeviceTimeout
            If no telemetry arrives for ``timeout_s`` of wall time.
        """
        self.poll(0.0)
        blocks = [self.read_telemetry()]
        start = self._latest_t_us
        next_beat = start
        wait = self.timeout_s if timeout_s is None else timeout_s
        last = time.monotonic()
        while True:
            if heartbeat_s > 0 and (next_beat is None or (self._latest_t_us or 0) >= next_beat):
                self.send_heartbeat()
                next_beat = (self._latest_t_us or 0) + int(heartbeat_s * 1e6)
            self.poll(0.01)
            block = self.read_telemetry()
            if len(block):
                last = time.monotonic()
                blocks.append(block)
                if start is None:
                    start = int(block.t_us[0])
                if self._latest_t_us - start >= duration_s * 1e6:
                    return TelemetryBlock.concatenate(blocks)
            elif time.monotonic() - last > wait:
                raise DeviceTimeout(
                    f"no telemetry from {self.port} for {wait:g} s" + self.link_summary()
                )

    @property
    def latest_time_us(self) -> int | None:
        """Device time (us, unwrapped) of the newest telemetry sample received."""
        return self._latest_t_us

    @property
    def frames_lost(self) -> int:
        """Device frames missing from the sequence, plus frames rejected by the checks."""
        s = self.decoder.stats
        return s.lost + s.bad_cobs + s.bad_crc + s.truncated + s.oversized

    # ---- internals -----------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        if self._serial is None:
            raise PortVanished(f"serial port {self.port} is closed")
        try:
            self._serial.write(data)
        except serial.SerialTimeoutException:
            raise DeviceTimeout(f"cannot write to {self.port}: the line is blocked") from None
        except (serial.SerialException, OSError) as exc:
            self._vanished(exc)

    def _vanished(self, exc: BaseException) -> None:
        self.close()
        gone = "" if os.path.exists(self.port) else f" ({self.port} no longer exists)"
        raise PortVanished(f"serial port {self.port} went away{gone}: {exc}") from None

    def _send(self, msg: proto.Message) -> int:
        seq = self._seq
        self._write(proto.encode_frame(seq, msg))
        self._seq = (seq + 1) & 0xFF
        return seq

    def _read(self, timeout_s: float) -> bytes:
        ser = self._serial
        if ser is None:
            raise PortVanished(f"serial port {self.port} is closed")
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                waiting = ser.in_waiting
                if waiting or timeout_s <= 0:
                    data = ser.read(waiting) if waiting else b""
                else:
                    data = ser.read(1)
                    if data and ser.in_waiting:
                        data += ser.read(ser.in_waiting)
                if data or time.monotonic() >= deadline:
                    return data
        except (serial.SerialException, OSError) as exc:
            self._vanished(exc)
            raise  # unreachable: _vanished raises

    def _pump(self, timeout_s: float, strict: bool = True) -> list[proto.Message]:
        """Read and decode; store telemetry; raise (after storing everything) on a fault or a
        reset when ``strict``."""
        data = self._read(timeout_s)
        if not data:
            return []
        self._last_rx_wall = time.monotonic()
        out: list[proto.Message] = []
        problem: DeviceError | None = None
        for frame in self.decoder.feed(data):
            msg = frame.message
            if isinstance(msg, proto.Telemetry):
                self._store(msg)
                if self._mode != Mode.IDLE and msg.samples[-1].flags & SampleFlag.FAULT:
                    problem = problem or self._fault(self.faults)
                continue
            if isinstance(msg, proto.Status):
                self.last_status = msg
                if msg.faults:
                    self.faults = msg.faults
                if self._session and not msg.flags & proto.StatusFlag.SESSION:
                    problem = problem or DeviceReset(
                        f"device on {self.port} reset: it reports no session"
                    )
                elif msg.faults and self._mode != Mode.IDLE:
                    problem = problem or self._fault(msg.faults)
            elif isinstance(msg, proto.Info) and self._session:
                problem = problem or DeviceReset(
                    f"device on {self.port} reset: it sent INFO unasked"
                )
            elif isinstance(msg, proto.ErrorReport):
                if msg.code == ErrorCode.NO_SESSION and self._session:
                    problem = problem or DeviceReset(
                        f"device on {self.port} reset: it lost the session (answered NO_SESSION); "
                        "mode and configuration are gone and the jaw is limp"
                    )
            out.append(msg)
        if problem is not None and strict:
            self._mode = Mode.IDLE
            if isinstance(problem, DeviceReset):
                self._session = False
            raise problem
        return out

    def _fault(self, faults: int) -> DeviceFault:
        names = fault_names(faults)
        why = {
            "WATCHDOG": "no host frame for 500 ms",
            "ESTOP": "emergency stop",
            "SENSOR": "potentiometer reading at a rail",
            "NUMERIC": "non-finite PID value",
        }
        reasons = ", ".join(why[n] for n in names.split("+") if n in why) or "fault"
        return DeviceFault(
            f"device on {self.port} made a safe stop (idle, jaw open): fault {names} ({reasons})",
            faults,
        )

    def _store(self, msg: proto.Telemetry) -> None:
        raw = msg.t0_us
        if (
            self._last_t_raw is not None
            and raw < self._last_t_raw
            and self._last_t_raw - raw > (1 << 31)
        ):
            self._t_offset += 1 << 32  # micros() wrapped
        self._last_t_raw = raw
        step = msg.decimation * 1000
        n = len(msg.samples)
        t = self._t_offset + raw + step * np.arange(n, dtype=np.int64)
        if self._next_t_us is not None and t[0] > self._next_t_us:
            self.samples_missing += int((t[0] - self._next_t_us) // max(step, 1))
        self._next_t_us = int(t[-1]) + step
        self._latest_t_us = int(t[-1])
        arr = np.array(
            [(s.reference_cdeg, s.command_cdeg, s.adc, s.flags) for s in msg.samples],
            dtype=_SAMPLE_DTYPE,
        )
        ref = np.where(arr["r"] == proto.CDEG_NONE, np.nan, arr["r"] / 100.0)
        cmd = np.where(arr["u"] == proto.CDEG_NONE, np.nan, arr["u"] / 100.0)
        adc = arr["adc"].astype(np.int64)
        pos = self.calibration.to_deg(adc) if self.calibration else np.full(n, np.nan)
        self._blocks.append(TelemetryBlock(t, ref, cmd, adc, pos, arr["flags"].copy()))

    def link_summary(self) -> str:
        """What the link looked like lately, for error messages ("; 3 corrupted frames...")."""
        s = self.decoder.stats
        idle = time.monotonic() - self._last_rx_wall
        if s.rejected:
            last = f" (last: {self.decoder.last_error})" if self.decoder.last_error else ""
            return f"; {s.rejected} corrupted frames received{last}"
        return f"; nothing received for {idle:.2f} s: the device is silent"

    def _request(self, msg: proto.Message, expect: type, timeout_s: float | None = None) -> Any:
        """Send ``msg`` and wait for its answer of type ``expect``; resend on silence."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        name = type(msg).__name__.upper()
        rejected_before = self.decoder.stats.rejected
        for _attempt in range(self.retries + 1):
            seq = self._send(msg)
            deadline = time.monotonic() + timeout
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                for answer in self._pump(
                    min(remaining, 0.05), strict=not isinstance(msg, proto.Hello)
                ):
                    if isinstance(answer, proto.ErrorReport) and answer.seq == seq:
                        self._refused(msg, answer)
                    if isinstance(answer, expect):
                        if isinstance(answer, proto.Status) and answer.last_rx_seq != seq:
                            continue  # a fault report or an answer to an earlier frame
                        if isinstance(msg, proto.Heartbeat) and answer.echo != msg.token:
                            continue
                        return answer
        corrupted = self.decoder.stats.rejected - rejected_before
        what = (
            f"no answer to {name} from {self.port} after {self.retries + 1} tries of {timeout:g} s"
        )
        if corrupted:
            raise LinkError(
                f"{what}: {corrupted} corrupted frames received (last: {self.decoder.last_error})"
            )
        raise DeviceTimeout(what + self.link_summary())

    def _refused(self, msg: proto.Message, err: proto.ErrorReport) -> None:
        name = type(msg).__name__.upper()
        code = ERROR_NAMES.get(err.code, f"code {err.code}")
        if err.code == ErrorCode.VERSION_MISMATCH:
            raise VersionMismatch(
                f"device on {self.port} speaks protocol version {err.detail}, this host speaks "
                f"{proto.PROTOCOL_VERSION}: update the firmware or the host",
                err.code,
                err.detail,
            )
        if err.code == ErrorCode.NO_SESSION and self._session:
            self._session = False
            raise DeviceReset(f"device on {self.port} reset: it answered {name} with NO_SESSION")
        detail = ""
        if err.code == ErrorCode.BAD_VALUE and isinstance(msg, proto.Configure):
            field_name = [f.name for f in fields(msg)][err.detail]
            detail = f": field {field_name}={getattr(msg, field_name)!r} refused"
        elif err.code == ErrorCode.FAULT_LATCHED:
            detail = f": fault {fault_names(err.detail)} latched (set IDLE to acknowledge)"
        raise DeviceRefused(f"device refused {name}: {code}{detail}", err.code, err.detail)

"""The host's handle on the gripper board: :class:`GripperDevice`.

It opens a serial port (a path such as ``/dev/ttyACM0`` or ``/dev/pts/7``, or any pyserial URL),
waits for the board to boot (opening the port resets a real Mega: ``boot_wait_s`` = 2 s by
default; the virtual device boots instantly, pass 0), does the version handshake, configures
the board's PID, limits and calibration, switches modes, streams setpoints and collects the
batched telemetry into arrays. Used as a context manager it always leaves the device stopped in
the safe (open) position, whatever happened inside the block.

Nothing the host sends is lost silently. Requests (HELLO, CONFIGURE, SET_MODE, HEARTBEAT) are
answered, and sent again when the answer does not come or the board reports the frame lost; a
mode change is checked against the mode the board reports. Setpoints are streamed without an
answer (50 Hz during a run); the board reports any host frame it missed (ERROR FRAMES_LOST) and
:class:`~gripper_env.hardware.host.command_log.CommandLog` sends a lost setpoint again unless a
newer
one replaced it. The setpoint a mode change starts from is confirmed before the mode changes (it
is read back from STATUS), as is any setpoint sent with ``confirm=True``; a command that does not
take after every retry raises :class:`~gripper_env.hardware.host.errors.CommandLost`.

Every failure is a :class:`~gripper_env.hardware.host.errors.DeviceError` subclass that says what
happened (:mod:`gripper_env.hardware.host.errors` lists them); telemetry arrives as
:class:`~gripper_env.hardware.host.telemetry.TelemetryBlock` s.

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
import time
from typing import Any

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.command_log import CommandLog, lost_sequence
from gripper_env.hardware.host.configuration import configure_message
from gripper_env.hardware.host.errors import (
    CommandLost,
    DeviceError,
    DeviceFault,
    DeviceReset,
    DeviceTimeout,
    LinkError,
    PortVanished,
    fault_error,
    refusal,
    version_mismatch,
)
from gripper_env.hardware.host.serial_port import (
    close_port,
    open_port,
    read_bytes,
    write_bytes,
)
from gripper_env.hardware.host.telemetry import TelemetryBlock, TelemetryClock
from gripper_env.hardware.protocol import ErrorCode, Mode, SampleFlag
from gripper_env.model.pid import PIDGains, PIDOptions

__all__ = ["BAUDRATE", "GripperDevice"]

BAUDRATE = 1_000_000
#: A request's wait widens per try (``timeout_s``, twice that, ...) up to this many times
#: ``timeout_s``: 0.5, 1 and 2 s for the default three tries.
REQUEST_WIDENING = 4.0
#: The handshake sends HELLO again, every ``timeout_s``, for at least this long (s) before it
#: gives up: the first answer after a port opens is the one a busy host or a slow USB bridge
#: delays most (a virtual board on a loaded 2-core machine went 1.5 s without answering). A
#: board that is there answers the first HELLO; one that is not is refused a few seconds later.
HANDSHAKE_PATIENCE_S = 5.0


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
        How many times a command whose answer did not come (or that the board reports lost, or
        a setpoint it does not hold) is sent again.
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
        self._serial: Any = None
        self._seq = 0
        self._session = False
        self._mode = Mode.IDLE
        self._blocks: list[TelemetryBlock] = []
        self._clock = TelemetryClock()
        self._token = 0
        self._last_rx_wall = time.monotonic()
        self.commands = CommandLog()
        self._setpoint_confirmed = False
        #: HELLOs of the last handshake whose INFO has not arrived: a slow board answers a
        #: HELLO sent again after the first answer (not a reset; see :meth:`handshake`).
        self._late_infos = 0
        self._hellos_sent = self._infos_seen = 0
        if open:
            self.open()

    # ---- connection ----------------------------------------------------------------------------

    def open(self) -> proto.Info:
        """Open the port, let the board boot, and do the handshake; return its INFO."""
        self._serial = open_port(self.port, self.baudrate)
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
            close_port(ser)

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
        self._hellos_sent = self._infos_seen = 0
        tries, total = 0, 0.0  # as many widening tries as HANDSHAKE_PATIENCE_S takes
        while tries < self.retries + 1 or (0 < self.timeout_s and total < HANDSHAKE_PATIENCE_S):
            total += self.timeout_s * min(2.0**tries, REQUEST_WIDENING)
            tries += 1
        info = self._request(proto.Hello(), proto.Info, tries=tries)
        # a board slower than the timeout answers the first HELLO after the host sent it again:
        # the INFOs still to come answer those HELLOs, which reached the board before anything
        # sent after this one (the link is first in, first out), so they are no reset
        self._late_infos = max(0, self._hellos_sent - self._infos_seen)
        if info.protocol_version != proto.PROTOCOL_VERSION:
            raise version_mismatch(self.port, info.protocol_version)
        self.info = info
        self.commands.new_session()
        self._setpoint_confirmed = False
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
            It must lie inside the board's hard range (``info.hard_jaw_min_deg`` ..
            ``hard_jaw_max_deg``, 21-92 deg by default).
        decimation : int
            One telemetry sample every ``decimation`` ticks (1 = 1 kHz).
        telemetry_batch : int
            Samples per telemetry frame (1..32).
        servo_us : (int, int)
            Servo pulse widths (us) at 0 and 180 deg; they must give the jaw range pulses inside
            the board's hard window (``info.hard_pulse_min_us`` .. ``hard_pulse_max_us``).

        Raises
        ------
        ValueError
            A jaw range or pulse mapping outside the board's hard limits (checked here, before
            anything is sent, and by the board again).
        """
        gains = gains or PIDGains(0.0, 0.0, 0.0)
        options = options or PIDOptions()
        if calibration is not None:
            self.calibration = calibration
        if self.calibration is None:
            raise ValueError("configure needs a calibration (python -m tuners.rig.calibrate)")
        self._check_hard_limits((float(jaw_deg[0]), float(jaw_deg[1])), servo_us)
        msg = configure_message(
            gains,
            options,
            self.calibration,
            jaw_min=float(jaw_deg[0]),
            jaw_max=float(jaw_deg[1]),
            servo_us_at_0=int(servo_us[0]),
            servo_us_at_180=int(servo_us[1]),
            decimation=int(decimation),
            telemetry_batch=int(telemetry_batch),
        )
        return self._request(msg, proto.Status)

    def set_mode(self, mode: int) -> proto.Status:
        """Switch to IDLE (safe position, acknowledges faults), OPEN_LOOP or CLOSED_LOOP.

        Before an active mode, the last setpoint sent is confirmed (:meth:`confirm_setpoint`),
        so the mode never starts from a setpoint that was lost; the board's answer must report
        the new mode.

        Raises
        ------
        CommandLost
            If the setpoint or the mode does not take after every retry.
        """
        if mode != Mode.IDLE and self.commands.latest_setpoint and not self._setpoint_confirmed:
            self.confirm_setpoint()
        status = self._request(proto.SetMode(mode), proto.Status)
        if status.mode != mode:
            raise CommandLost(
                f"device on {self.port} answered SET_MODE({mode}) in mode {status.mode}"
            )
        self._mode = mode
        if mode == Mode.IDLE:
            self.faults = 0
        return status

    def set_setpoint(self, angle_deg: float, *, confirm: bool = False) -> None:
        """Send the open-loop command or closed-loop reference (deg).

        Parameters
        ----------
        angle_deg : float
            The setpoint (deg); the board clamps it into the jaw range.
        confirm : bool
            Wait until the board holds it (:meth:`confirm_setpoint`). Without, no answer is
            awaited (the 50 Hz stream of a run); a setpoint the board reports lost is sent again
            unless a newer one replaced it, and the one a mode change starts from is confirmed
            by :meth:`set_mode`.
        """
        if not math.isfinite(angle_deg):
            raise ValueError(f"setpoint must be a finite angle, got {angle_deg}")
        self._send(proto.Setpoint(float(angle_deg)))
        self._setpoint_confirmed = False
        if confirm:
            self.confirm_setpoint()

    def confirm_setpoint(self) -> proto.Status:
        """Make sure the board holds the last setpoint sent: read it back from a STATUS (one
        HEARTBEAT round trip), sending it again while it does not.

        Returns
        -------
        Status
            The STATUS that shows it.

        Raises
        ------
        ValueError
            If no setpoint was sent in this session.
        CommandLost
            If the board does not hold it after :attr:`retries` more tries.
        """
        msg = self.commands.latest_setpoint
        if msg is None:
            raise ValueError("no setpoint was sent in this session")
        want = np.float32(msg.angle_deg)
        for attempt in range(self.retries + 1):
            if attempt:
                self._send(msg)
                self.commands.resent += 1
            status, _ = self.heartbeat()
            if np.float32(status.setpoint_deg) == want:
                self._setpoint_confirmed = True
                return status
        raise CommandLost(
            f"device on {self.port} does not hold SETPOINT {msg.angle_deg:g} deg after "
            f"{self.retries + 1} tries (it holds {status.setpoint_deg:g} deg)" + self.link_summary()
        )

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
        start = self._clock.latest_us
        next_beat = start
        wait = self.timeout_s if timeout_s is None else timeout_s
        last = time.monotonic()
        while True:
            if heartbeat_s > 0 and (next_beat is None or (self._clock.latest_us or 0) >= next_beat):
                self.send_heartbeat()
                next_beat = (self._clock.latest_us or 0) + int(heartbeat_s * 1e6)
            self.poll(0.01)
            block = self.read_telemetry()
            if len(block):
                last = time.monotonic()
                blocks.append(block)
                if start is None:
                    start = int(block.t_us[0])
                if (self._clock.latest_us or 0) - start >= duration_s * 1e6:
                    return TelemetryBlock.concatenate(blocks)
            elif time.monotonic() - last > wait:
                raise DeviceTimeout(
                    f"no telemetry from {self.port} for {wait:g} s" + self.link_summary()
                )

    @property
    def latest_time_us(self) -> int | None:
        """Device time (us, unwrapped) of the newest telemetry sample received."""
        return self._clock.latest_us

    @property
    def samples_missing(self) -> int:
        """Telemetry samples that never arrived (gaps in the device time)."""
        return self._clock.samples_missing

    @property
    def frames_lost(self) -> int:
        """Device frames missing from the sequence, plus frames rejected by the checks."""
        s = self.decoder.stats
        return s.lost + s.bad_cobs + s.bad_crc + s.truncated + s.oversized + s.damaged

    @property
    def commands_lost(self) -> int:
        """Host frames the board reported missing (each resent, superseded, or of no
        consequence: :mod:`~gripper_env.hardware.host.command_log`)."""
        return self.commands.lost

    # ---- internals -----------------------------------------------------------------------------

    def _port(self) -> Any:
        if self._serial is None:
            raise PortVanished(f"serial port {self.port} is closed")
        return self._serial

    def _write(self, data: bytes) -> None:
        try:
            write_bytes(self._port(), self.port, data)
        except PortVanished:
            self.close()
            raise

    def _send(self, msg: proto.Message) -> int:
        if isinstance(msg, proto.Hello):
            self._hellos_sent += 1
        seq = self._seq
        self._write(proto.encode_frame(seq, msg))
        self._seq = (seq + 1) & 0xFF
        self.commands.sent(seq, msg)
        return seq

    def _check_hard_limits(self, jaw: tuple[float, float], servo_us: tuple[int, int]) -> None:
        """Refuse a jaw range or pulse mapping outside the board's hard limits (INFO), naming
        the limit, before anything is sent."""
        info = self.info
        if info is None:
            return
        lo, hi = info.hard_jaw_min_deg, info.hard_jaw_max_deg
        if not lo <= jaw[0] < jaw[1] <= hi:
            raise ValueError(
                f"jaw_deg {jaw[0]:g}..{jaw[1]:g} deg lies outside the board's hard range "
                f"{lo:g}..{hi:g} deg (compiled into its firmware)"
            )
        us0, us180 = servo_us
        for deg in jaw:
            us = ((2 * us0 + 0.5) + deg * 2 * (us180 - us0) / 180.0) // 1 / 2
            if not info.hard_pulse_min_us <= us <= info.hard_pulse_max_us:
                raise ValueError(
                    f"servo_us {us0}/{us180} gives {deg:g} deg a pulse of {us:g} us, outside "
                    f"the board's hard window {info.hard_pulse_min_us:g}.."
                    f"{info.hard_pulse_max_us:g} us"
                )

    def _read(self, timeout_s: float) -> bytes:
        try:
            return read_bytes(self._port(), self.port, timeout_s)
        except PortVanished:
            self.close()
            raise

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
            elif isinstance(msg, proto.Info) and not self._session:
                self._infos_seen += 1  # answers to this handshake's HELLOs
            elif isinstance(msg, proto.Info) and self._session:
                if self._late_infos > 0:  # the answer to a HELLO sent again (see handshake)
                    self._late_infos -= 1
                    continue
                problem = problem or DeviceReset(
                    f"device on {self.port} reset: it sent INFO unasked"
                )
            elif isinstance(msg, proto.ErrorReport):
                for command in self.commands.to_resend(msg):  # FRAMES_LOST: a lost command
                    self._send(command)
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
        return fault_error(self.port, faults)

    def _store(self, msg: proto.Telemetry) -> None:
        self._blocks.append(self._clock.block(msg, self.calibration))

    def link_summary(self) -> str:
        """What the link looked like lately, for error messages ("; 3 corrupted frames...")."""
        s = self.decoder.stats
        idle = time.monotonic() - self._last_rx_wall
        if s.rejected:
            last = f" (last: {self.decoder.last_error})" if self.decoder.last_error else ""
            return f"; {s.rejected} corrupted frames received{last}"
        return f"; nothing received for {idle:.2f} s: the device is silent"

    def _request(
        self,
        msg: proto.Message,
        expect: type,
        timeout_s: float | None = None,
        tries: int | None = None,
    ) -> Any:
        """Send ``msg`` and wait for its answer of type ``expect``; resend on silence (``tries``
        sends in all, default ``retries + 1``). Each try waits twice as long as the one before,
        up to :data:`REQUEST_WIDENING` times ``timeout_s`` (a busy host or board answers late, not
        never), and an answer to any of the tries is taken."""
        timeout = self.timeout_s if timeout_s is None else timeout_s
        tries = self.retries + 1 if tries is None else tries
        name = type(msg).__name__.upper()
        rejected_before = self.decoder.stats.rejected
        sent: set[int] = set()
        waited = 0.0
        for attempt in range(tries):
            seq = self._send(msg)
            sent.add(seq)
            wait = timeout * min(2.0**attempt, REQUEST_WIDENING)
            waited += wait
            deadline = time.monotonic() + wait
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                answers = self._pump(min(remaining, 0.05), strict=not isinstance(msg, proto.Hello))
                if any(
                    seq in lost_sequence(a) for a in answers if isinstance(a, proto.ErrorReport)
                ):
                    self.commands.resent += 1
                    break  # the board reports it lost: send it again now
                for answer in answers:
                    if (
                        isinstance(answer, proto.ErrorReport)
                        and answer.code == ErrorCode.FRAMES_LOST
                    ):
                        continue  # a report on other frames, not an answer
                    if isinstance(answer, proto.ErrorReport) and answer.seq in sent:
                        self._refused(msg, answer)
                    if isinstance(answer, expect):
                        if isinstance(answer, proto.Status) and answer.last_rx_seq not in sent:
                            continue  # a fault report or an answer to an earlier frame
                        if (
                            isinstance(msg, proto.Heartbeat)
                            and isinstance(answer, proto.Status)
                            and answer.echo != msg.token
                        ):
                            continue
                        return answer
        corrupted = self.decoder.stats.rejected - rejected_before
        what = f"no answer to {name} from {self.port} after {tries} tries over {waited:.3g} s"
        if corrupted:
            raise LinkError(
                f"{what}: {corrupted} corrupted frames received (last: {self.decoder.last_error})"
            )
        raise DeviceTimeout(what + self.link_summary())

    def _refused(self, msg: proto.Message, err: proto.ErrorReport) -> None:
        if err.code == ErrorCode.NO_SESSION and self._session:
            self._session = False
            name = type(msg).__name__.upper()
            raise DeviceReset(f"device on {self.port} reset: it answered {name} with NO_SESSION")
        raise refusal(self.port, msg, err)

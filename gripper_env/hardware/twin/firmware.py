"""The board's firmware logic in Python: the twin of ``Device`` in ``gripper_device.h``.

:class:`Firmware` is the protocol session, mode state machine, PID, safety (jaw clamp, watchdog,
ESTOP, sensor and numeric faults) and telemetry batching of the Arduino sketch, line for line,
so that the virtual device (:mod:`gripper_env.hardware.virtual`) behaves like the board. It is
hardware-free in the same way as the C++ class: feed it received bytes with :meth:`receive`,
call :meth:`tick` once per 1 ms control period with the ADC reading, apply
:attr:`servo_command_deg` while :attr:`servo_on`, and drain :attr:`tx` (bytes for the host).

The safety unit's twin (jaw clamp, calibration, rails, limits) is
:mod:`gripper_env.hardware.safety`; the stream decoder is the host's
:class:`~gripper_env.hardware.protocol.FrameSplitter`, which works like the firmware's. The PID
is :func:`gripper_env.model.pid.pid_update`, the same equations as the firmware's
``pid_update``; arithmetic is float64 here (like the host build of the C++ harness), float32 on
the board. The specification of every message is ``firmware/PROTOCOL.md``.

Examples
--------
>>> from gripper_env.hardware import protocol as proto
>>> fw = Firmware(device_id=7)
>>> fw.receive(proto.encode_frame(0, proto.Hello()), now_us=0)
>>> proto.FrameDecoder().feed(fw.take_tx())[0].message.device_id
7
"""

from __future__ import annotations

import math

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.protocol.reports import SAMPLE_STRUCT, TELEMETRY_HEADER_STRUCT
from gripper_env.hardware.safety import (
    HARD_PULSE_TICKS,
    JAW_HARD_MAX_DEG,
    JAW_HARD_MIN_DEG,
    JAW_OPEN_DEG,
    SENSOR_FAULT_TICKS,
    WATCHDOG_TIMEOUT_US,
    adc_at_rail,
    adc_to_deg,
    clamp_jaw,
    servo_pulse_ticks,
)
from gripper_env.hardware.safety import finite as _finite
from gripper_env.hardware.twin.firmware_config import (
    TICK_PERIOD_US,
    FirmwareConfig,
    validate_configure,
)
from gripper_env.model.pid import G_HELD, STATE_SIZE, pid_update

__all__ = ["TX_QUEUE_CAPACITY", "UART_BYTES_PER_TICK", "Firmware"]

FIRMWARE_VERSION = (0, 3, 0)  # the C++ FIRMWARE_VERSION_MAJOR/MINOR/PATCH
TX_QUEUE_CAPACITY = 512  # bytes in the board's transmit queue
UART_BYTES_PER_TICK = 100  # 1 Mbaud 8N1 drains 100 bytes per 1 ms tick
_DT_S = TICK_PERIOD_US / 1e6


def _to_cdeg(deg: float) -> int:
    """Centi-degrees (i16) of an angle: ``deg * 100`` rounded half away from zero, exactly,
    saturated to +-32767; NaN to CDEG_NONE (C++ ``to_cdeg``)."""
    if deg != deg:
        return proto.CDEG_NONE
    if math.isinf(deg):
        return 32767 if deg > 0 else -32767
    num, den = deg.as_integer_ratio()  # exact; den is a power of two
    c = (2 * abs(num) * 100 + den) // (2 * den)  # floor(|deg| * 100 + 1/2)
    c = min(c, 32767)
    return -c if num < 0 else c


class Firmware:
    """The device state machine of the gripper firmware (see the module docstring).

    Parameters
    ----------
    device_id : int
        Board id reported in INFO (u32; 0xFFFFFFFF if the EEPROM was never written).
    now_us : int
        Device time (us) at boot.

    Attributes
    ----------
    tx : bytearray
        The transmit queue (at most :data:`TX_QUEUE_CAPACITY` bytes, whole frames or nothing);
        the caller drains it (:meth:`take_tx`, or :meth:`uart_drain` at the UART's rate).
    """

    def __init__(self, device_id: int = 0xFFFFFFFF, now_us: int = 0) -> None:
        self.tx = bytearray()
        self.begin(device_id, now_us)

    # ---- lifecycle -----------------------------------------------------------------------------

    def begin(self, device_id: int, now_us: int) -> None:
        """Power-on state (also what a reset of the board does): no session, servo limp."""
        self.device_id = device_id
        self.rx = proto.FrameSplitter()
        self.tx.clear()
        self.tx_seq = 0
        self.session = False
        self.configured = False
        self.cfg = FirmwareConfig()
        self.mode = proto.Mode.IDLE
        self.faults = 0
        self.servo_on = False
        self.entry_pending = False
        self.have_setpoint = False
        self.setpoint = JAW_OPEN_DEG
        self.reference = JAW_OPEN_DEG
        self.command = JAW_OPEN_DEG
        self.pid_state = np.zeros(STATE_SIZE)
        self.last_rx_us = now_us & 0xFFFFFFFF
        self.now_us = now_us & 0xFFFFFFFF
        self.echo = 0
        self.last_rx_seq = 0
        self.refused = self.tx_dropped = self.overruns = self.rx_overflow = 0
        self.rail_ticks = 0
        self._samples: list[bytes] = []
        self._t0_us = 0
        self._telemetry_decimation = 1
        self._decimation_count = 0
        self._rx_type = 0
        self._rx_seq = 0

    # ---- inputs --------------------------------------------------------------------------------

    def receive(self, data: bytes, now_us: int) -> None:
        """Feed bytes received from the host at device time ``now_us``."""
        self.now_us = now_us & 0xFFFFFFFF
        for seq, type_id, payload, gap in self.rx.split(data):
            self._handle_frame(seq, type_id, payload, gap)

    def rx_lost(self, n: int) -> None:
        """``n`` host bytes were lost before the next byte received (a full receive buffer, a
        UART overrun): counted, and the frame they belonged to is dropped (C++ ``rx_lost``)."""
        self.rx_overflow += n
        self.rx.abort_frame()

    def tick(self, now_us: int, adc: int, overrun: bool = False) -> None:
        """One 1 ms control period at device time ``now_us`` with the ADC reading ``adc``."""
        now_us &= 0xFFFFFFFF
        self.now_us = now_us
        flags = 0
        if overrun:
            self.overruns += 1
            flags = proto.SampleFlag.OVERRUN
        mode = self.mode
        if mode != proto.Mode.IDLE and ((now_us - self.last_rx_us) & 0xFFFFFFFF) >= (
            WATCHDOG_TIMEOUT_US
        ):
            self._safe_stop(proto.Fault.WATCHDOG)
        cfg = self.cfg
        y = adc_to_deg(adc, cfg.adc_at_lo, cfg.adc_at_hi)
        if self.mode == proto.Mode.CLOSED_LOOP:
            self.rail_ticks = self.rail_ticks + 1 if adc_at_rail(adc) else 0
            if self.rail_ticks >= SENSOR_FAULT_TICKS:
                self._safe_stop(proto.Fault.SENSOR)
        if self.entry_pending:
            self._enter_mode(y)
        mode = self.mode
        safe = cfg.jaw_max
        if mode != proto.Mode.IDLE:
            reference = clamp_jaw(self.setpoint, cfg.jaw_min, cfg.jaw_max, safe)
            if self.have_setpoint and reference != self.setpoint:
                flags |= proto.SampleFlag.CLAMPED
            self.reference = reference
            if mode == proto.Mode.OPEN_LOOP:
                self.command = reference
            else:
                u, v = pid_update(
                    reference, y, cfg.p, cfg.i, cfg.d, cfg.n, _DT_S, cfg.u_min, cfg.u_max,
                    cfg.anti_windup, cfg.kb, cfg.sign, cfg.d_on_meas, self.pid_state,
                    cfg.grasp, cfg.squeeze, cfg.push, cfg.shortfall, cfg.still, float(cfg.dwell),
                )  # fmt: skip
                st = self.pid_state
                if not (_finite(v) and _finite(st[0]) and _finite(st[1]) and _finite(st[5])):
                    self._safe_stop(proto.Fault.NUMERIC)
                else:
                    if u != v:
                        flags |= proto.SampleFlag.SATURATED
                    if st[G_HELD] != 0.0:
                        flags |= proto.SampleFlag.GRASP
                    self.command = clamp_jaw(u, cfg.jaw_min, cfg.jaw_max, safe)
        if self.mode == proto.Mode.IDLE:
            self.reference = safe
            self.command = safe
        self._record_sample(adc, flags)

    # ---- outputs -------------------------------------------------------------------------------

    @property
    def servo_command_deg(self) -> float:
        """The servo command (deg), always inside the jaw range; meaningful while servo_on."""
        return self.command

    def servo_pulse_us(self) -> float:
        """Servo pulse width (us, 0.5 us resolution) for the current command, clamped into the
        hard pulse window."""
        cfg = self.cfg
        return servo_pulse_ticks(self.command, cfg.servo_us_at_0, cfg.servo_us_at_180) / 2.0

    def take_tx(self) -> bytes:
        """All queued transmit bytes (the queue is emptied)."""
        out = bytes(self.tx)
        self.tx.clear()
        return out

    def uart_drain(self, max_bytes: int = UART_BYTES_PER_TICK) -> bytes:
        """At most ``max_bytes`` queued bytes, as the UART sends them in one tick."""
        out = bytes(self.tx[:max_bytes])
        del self.tx[:max_bytes]
        return out

    def status(self) -> proto.Status:
        """The STATUS the device would send now."""
        rx = self.rx.stats
        flags = (
            (proto.StatusFlag.SESSION if self.session else 0)
            | (proto.StatusFlag.CONFIGURED if self.configured else 0)
            | (proto.StatusFlag.SERVO_ON if self.servo_on else 0)
        )
        return proto.Status(
            device_time_us=self.now_us,
            echo=self.echo,
            mode=self.mode,
            faults=self.faults,
            flags=flags,
            last_rx_seq=self.last_rx_seq,
            frames_ok=rx.frames & 0xFFFFFFFF,
            frames_lost=min(rx.lost, 0xFFFF),
            bad_crc=min(rx.bad_crc, 0xFFFF),
            bad_frame=min(rx.bad_cobs + rx.truncated + rx.oversized + rx.damaged, 0xFFFF),
            refused=min(self.refused, 0xFFFF),
            tx_dropped=min(self.tx_dropped, 0xFFFF),
            overruns=min(self.overruns, 0xFFFF),
            rx_overflow=min(self.rx_overflow, 0xFFFF),
            setpoint_deg=float(np.float32(self.setpoint)) if self.have_setpoint else math.nan,
        )

    # ---- internals (the C++ private methods, same names) ---------------------------------------

    def _safe_stop(self, fault: int) -> None:
        was_active = self.mode != proto.Mode.IDLE
        self.mode = proto.Mode.IDLE
        self.entry_pending = False
        self.command = self.cfg.jaw_max
        self.reference = self.cfg.jaw_max
        self.rail_ticks = 0
        if fault:
            self.faults |= fault
            if was_active or fault == proto.Fault.ESTOP:
                self._send_status()

    def _enter_mode(self, y: float) -> None:
        self.entry_pending = False
        cfg = self.cfg
        if self.mode == proto.Mode.OPEN_LOOP:
            if not self.have_setpoint:
                self.setpoint = self.command if self.servo_on else cfg.jaw_max
        elif self.mode == proto.Mode.CLOSED_LOOP:
            if not self.have_setpoint:
                self.setpoint = y
            u0 = (
                self.command
                if self.servo_on
                else clamp_jaw(y, cfg.jaw_min, cfg.jaw_max, cfg.jaw_max)
            )
            # PID.reset: the integrator at u0, no derivative kick, no grasp (the jaw at y)
            self.pid_state[:] = (u0, -cfg.sign * y if cfg.d_on_meas else 0.0, 0.0, y, 0.0, y)
        self.have_setpoint = True
        self.servo_on = True

    def _handle_frame(self, seq: int, type_id: int, payload: bytes, gap: int) -> None:
        self.last_rx_seq = seq
        self.last_rx_us = self.now_us
        self._rx_type, self._rx_seq = type_id, seq
        n = len(payload)
        # Host frames missing before this one (a HELLO starts a new sequence): said at once.
        if self.session and type_id != proto.Hello.TYPE and gap:
            self._send(proto.ErrorReport(proto.ErrorCode.FRAMES_LOST, 0, (seq - gap) & 0xFF, gap))
        if type_id == proto.Estop.TYPE:
            if n != 0:
                return self._refuse(proto.ErrorCode.BAD_LENGTH, n)
            self._safe_stop(proto.Fault.ESTOP)
            return None
        if type_id == proto.Hello.TYPE:
            if n != 2:
                return self._refuse(proto.ErrorCode.BAD_LENGTH, n)
            self._safe_stop(0)
            if proto.Hello.decode(payload).protocol_version != proto.PROTOCOL_VERSION:
                self.session = False
                return self._refuse(proto.ErrorCode.VERSION_MISMATCH, proto.PROTOCOL_VERSION)
            self._start_session()
            return None
        if type_id >= 0x80 or type_id < proto.Hello.TYPE or type_id > proto.Estop.TYPE:
            return self._refuse(proto.ErrorCode.UNKNOWN_TYPE, type_id)
        if not self.session:
            return self._refuse(proto.ErrorCode.NO_SESSION, 0)
        cls = proto.MESSAGE_TYPES[type_id]
        try:
            msg = cls.decode(payload)
        except proto.PayloadLengthError:
            return self._refuse(proto.ErrorCode.BAD_LENGTH, n)
        if isinstance(msg, proto.Configure):
            config, field_index = validate_configure(msg)
            if config is None:
                return self._refuse(proto.ErrorCode.BAD_VALUE, field_index)
            self._apply_config(config)
            self._send_status()
        elif isinstance(msg, proto.SetMode):
            mode = msg.mode
            if mode > proto.Mode.CLOSED_LOOP:
                return self._refuse(proto.ErrorCode.BAD_VALUE, 0)
            if mode == proto.Mode.IDLE:
                self._safe_stop(0)
                self.faults = 0  # SET_MODE(IDLE) acknowledges latched faults
            else:
                if self.faults:
                    return self._refuse(proto.ErrorCode.FAULT_LATCHED, self.faults)
                if mode == proto.Mode.CLOSED_LOOP and not self.configured:
                    return self._refuse(proto.ErrorCode.NOT_CONFIGURED, 0)
                if mode != self.mode:
                    self.mode = mode
                    self.entry_pending = True
            self._send_status()
        elif isinstance(msg, proto.Setpoint):
            if not _finite(msg.angle_deg):
                return self._refuse(proto.ErrorCode.BAD_VALUE, 0)
            self.setpoint = msg.angle_deg
            self.have_setpoint = True
        elif isinstance(msg, proto.ProfileChunk):
            return self._refuse(proto.ErrorCode.UNSUPPORTED, 0)
        elif isinstance(msg, proto.Heartbeat):
            self.echo = msg.token
            self._send_status()
        return None

    def _start_session(self) -> None:
        self.session = True
        self.faults = 0
        self._apply_config(FirmwareConfig())
        self.configured = False  # closed loop needs a CONFIGURE in this session
        self.have_setpoint = False
        self.rx.forgive_last_gap()  # a HELLO starts a new host sequence
        major, minor, patch = FIRMWARE_VERSION
        self._send(
            proto.Info(
                proto.PROTOCOL_VERSION,
                major,
                minor,
                patch,
                self.device_id,
                TICK_PERIOD_US,
                proto.TELEMETRY_MAX_SAMPLES,
                proto.MAX_PAYLOAD,
                JAW_HARD_MIN_DEG,
                JAW_HARD_MAX_DEG,
                HARD_PULSE_TICKS[0] / 2.0,
                HARD_PULSE_TICKS[1] / 2.0,
            )
        )

    def _apply_config(self, c: FirmwareConfig) -> None:
        old = self.cfg
        structure_changed = (
            c.sign != old.sign or c.d_on_meas != old.d_on_meas or c.grasp != old.grasp
        )
        if c.decimation != old.decimation or c.batch != old.batch:
            self._flush_telemetry()
            self._decimation_count = 0
        self.cfg = c
        self.configured = True
        # A new sign or derivative input changes what xf means, and the grasp mode switched on
        # or off what the state holds: re-enter bumplessly.
        if structure_changed and self.mode == proto.Mode.CLOSED_LOOP:
            self.entry_pending = True

    def _refuse(self, code: int, detail: int) -> None:
        self.refused += 1
        self._send(proto.ErrorReport(code, self._rx_type, self._rx_seq, detail & 0xFFFF))

    def _send_status(self) -> None:
        self._send(self.status())

    def _send(self, msg: proto.Message) -> None:
        self._send_raw(msg.TYPE, msg.encode())

    def _send_raw(self, type_id: int, payload: bytes) -> None:
        frame = proto.encode_raw_frame(self.tx_seq, type_id, payload)
        # The sequence number advances even for a dropped frame, so the host sees the gap.
        self.tx_seq = (self.tx_seq + 1) & 0xFF
        if len(frame) > TX_QUEUE_CAPACITY - len(self.tx):
            self.tx_dropped += 1
        else:
            self.tx += frame

    def _flush_telemetry(self) -> None:
        if self._samples:
            header = TELEMETRY_HEADER_STRUCT.pack(
                self._t0_us, self._telemetry_decimation, len(self._samples)
            )
            self._send_raw(proto.Telemetry.TYPE, header + b"".join(self._samples))
        self._samples = []

    def _record_sample(self, adc: int, flags: int) -> None:
        cfg = self.cfg
        if not self.session or cfg.decimation == 0:
            return
        if self._decimation_count > 0:
            self._decimation_count -= 1
            return
        self._decimation_count = cfg.decimation - 1
        if not self._samples:
            self._t0_us = self.now_us
            self._telemetry_decimation = cfg.decimation
        flags |= (
            (self.mode & proto.SampleFlag.MODE_MASK)
            | (proto.SampleFlag.FAULT if self.faults else 0)
            | (proto.SampleFlag.SERVO_ON if self.servo_on else 0)
        )
        command = _to_cdeg(self.command) if self.servo_on else proto.CDEG_NONE
        self._samples.append(SAMPLE_STRUCT.pack(_to_cdeg(self.reference), command, adc, flags))
        if len(self._samples) >= cfg.batch:
            self._flush_telemetry()

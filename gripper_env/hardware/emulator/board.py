"""The compiled Mega 2560 firmware in the loop: the real image under simavr, on emulated time.

Two layers:

* :class:`~gripper_env.hardware.emulator.mega2560.Mega2560`
  (:mod:`gripper_env.hardware.emulator.mega2560`)
  loads ``firmware/build-mega/gripper.elf`` (what ``firmware/build.sh`` produces) into an
  emulated ATmega2560 at 16 MHz through the harness ``firmware/emulator/board.c`` (a small C
  library over Debian's ``libsimavr``, loaded with :mod:`ctypes`). It is the rig's view of the
  board: bytes on UART0 (paced at the line rate), the voltage on A0 in ADC counts, the servo
  pulses Timer1 drives on pin 11, edges of the firmware's timing pins (13: control path, 12:
  telemetry frame), the stack's low-water mark.
* :class:`EmulatedBoard` wires it to the simulated gripper (:class:`~gripper_env.hardware.
  virtual_rig.VirtualRig`, the project's simulation core) one millisecond at a time: the rig's
  potentiometer reading goes onto A0, the CPU runs, each servo pulse's width becomes the servo's
  angle (the firmware's pulse conversion inverted) when the pulse ends, and the rig takes one
  physics step. :class:`~gripper_env.hardware.virtual.VirtualDevice` puts it behind a pty, so the
  host tools talk to the real firmware exactly as to a board: ``python -m
  gripper_env.hardware.emulator.board`` prints the port.

Emulated time (CPU cycles at 16 MHz) is the only clock: the same bytes at the same emulated
instants give the same pulses, whatever the host's speed.

The servo of the emulated rig gets the firmware's real command path, so the rig's preset keeps
its friction, stops and sensor but not its command quantisation and refresh: the pulse has the
timer's 0.5 us resolution (about 0.05 deg) and arrives every 20 ms at the timer's own phase.

Both the image and the harness are built from the project's own scripts (``firmware/build.sh``,
``firmware/emulator/build.sh``); :mod:`gripper_env.hardware.emulator.build` calls them.

Examples
--------
>>> from gripper_env.hardware.twin.rig import VirtualRig
>>> board = EmulatedBoard(VirtualRig("test2", "actual", pulse_train=True))  # doctest: +SKIP
>>> board.run(50)  # 50 ms: the firmware boots  # doctest: +SKIP
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.mega2560 import (
    CYCLES_PER_MS,
    CYCLES_PER_US,
    EDGE_DTYPE,
    EMULATED_DEVICE_ID,
    PULSE_DTYPE,
    Mega2560,
)

if TYPE_CHECKING:
    from gripper_env.hardware.twin.rig import VirtualRig

__all__ = ["EmulatedBoard"]

#: Bytes the line to the emulated board holds (``RX_CAP`` of firmware/emulator/board.c).
RX_LINE_BYTES = 1 << 16
SERVO_US = (544, 2400)  # the emulated servo's pulse widths at 0 and 180 deg (hobby-servo standard)
SERVO_LIMP_MS = 25  # a servo that sees no pulse for this long stops driving (one frame lost)
TIMING_PINS = (("B", 7), ("B", 6))  # firmware marks: control path (pin 13), telemetry (pin 12)


class EmulatedBoard:
    """The compiled firmware on an emulated Mega 2560, wired to a simulated rig (module docstring).

    It has the interface :class:`~gripper_env.hardware.virtual.VirtualDevice` drives a board
    through (:meth:`step`, :meth:`receive`, :meth:`uart_out`, :meth:`reset`, :attr:`active`,
    :attr:`last_rx_us`), and can be driven directly, deterministically, by a test that writes
    host frames at chosen emulated instants.

    Parameters
    ----------
    rig : VirtualRig
        The simulated gripper, made with ``pulse_train=True``: its preset's command quantisation
        and refresh give way to the firmware's real pulse train (see the module docstring).
    image, harness : path, optional
        Firmware image and harness library (:class:`Mega2560`).
    device_id : int
        Board id in EEPROM (reported in INFO).
    servo_us : (int, int)
        The servo's pulse widths (us) at 0 and 180 deg.
    record : bool
        Keep every servo pulse and timing-pin edge (:attr:`pulses`, :meth:`edges`) for analysis.

    Attributes
    ----------
    mega : Mega2560
        The emulated MCU.
    command_deg : float or None
        The servo's current command (deg), from the last pulse; ``None`` while the servo gets no
        pulses (limp).
    ms : int
        Milliseconds of emulated time since power-on.
    """

    firmware = None  # the Python twin's state is not there to inspect: this is the real image

    def __init__(
        self,
        rig: VirtualRig,
        *,
        image: str | os.PathLike[str] | None = None,
        harness: str | os.PathLike[str] | None = None,
        device_id: int = EMULATED_DEVICE_ID,
        servo_us: tuple[float, float] = SERVO_US,
        record: bool = False,
    ) -> None:
        if not rig.pulse_train:
            raise ValueError(
                "the emulated board drives the servo with the firmware's own pulses: give it a "
                "VirtualRig(..., pulse_train=True)"
            )
        self.rig = rig
        self.mega = Mega2560(image, harness, device_id)
        self.device_id = device_id
        self.servo_us = (float(servo_us[0]), float(servo_us[1]))
        self.record = record
        self.ms = 0
        self.command_deg: float | None = None
        self.mode = proto.Mode.IDLE
        self.last_rx_us = 0
        self._last_pulse_end: int | None = None
        self._pulses: list[np.ndarray] = []
        self._edges: list[np.ndarray] = []
        self._tx = proto.FrameDecoder(synced=False)
        if record:
            for port, bit in TIMING_PINS:
                self.mega.watch_pin(port, bit)

    def close(self) -> None:
        """Free the emulated MCU."""
        self.mega.close()

    # ---- the board interface of VirtualDevice ------------------------------------------------

    @property
    def active(self) -> bool:
        """The firmware reported an active mode (open or closed loop) last."""
        return self.mode != proto.Mode.IDLE

    def rx_room(self) -> int:
        """Bytes the line to the board can take now (:data:`RX_LINE_BYTES` less those on it):
        a host that writes faster than the line carries them waits (flow control)."""
        return RX_LINE_BYTES - self.mega.rx_pending

    def receive(self, data: bytes, now_us: int | None = None) -> None:
        """Bytes from the host: onto the RX line now, one frame time apart.

        Raises
        ------
        RuntimeError
            More than :meth:`rx_room` bytes (the caller reads no more than that).
        """
        if self.mega.write(data) < len(data):
            raise RuntimeError("the emulated RX line holds 64 KiB: the host wrote faster than that")
        self.last_rx_us = self.ms * 1000 if now_us is None else now_us

    def step(self, now_us: int | None = None, overrun: bool = False) -> None:
        """One millisecond: ADC <- rig, run the CPU, servo pulses -> rig, one physics step.

        ``now_us`` and ``overrun`` are the Python twin's inputs; the firmware keeps its own time.
        """
        self.mega.set_adc(self.rig.adc)
        self.mega.run_until((self.ms + 1) * CYCLES_PER_MS)
        pulses = self.mega.read_pulses()
        if len(pulses):
            last = pulses[-1]
            us0, us180 = self.servo_us
            width_us = float(last["width"]) / CYCLES_PER_US
            self.command_deg = (width_us - us0) * 180.0 / (us180 - us0)
            self._last_pulse_end = int(last["start"]) + int(last["width"])
            if self.record:
                self._pulses.append(pulses)
        if self._last_pulse_end is not None and (
            self.mega.cycle - self._last_pulse_end > SERVO_LIMP_MS * CYCLES_PER_MS
        ):
            self.command_deg = None
        if self.record:
            self._edges.append(self.mega.read_edges())
        self.rig.step(self.command_deg)
        self.ms += 1

    def run(self, ms: int) -> None:
        """:meth:`step` ``ms`` times."""
        for _ in range(ms):
            self.step()

    def uart_out(self, max_bytes: int = 0) -> bytes:
        """Bytes the firmware transmitted since the last call (the UART cannot hold them back,
        so ``max_bytes`` is ignored)."""
        data = self.mega.read()
        if data:
            for frame in self._tx.feed(data):
                msg = frame.message
                if isinstance(msg, proto.Telemetry):
                    self.mode = msg.samples[-1].flags & proto.SampleFlag.MODE_MASK
                elif isinstance(msg, proto.Status):
                    self.mode = msg.mode
        return data

    def reset(self, now_us: int | None = None) -> None:
        """Pull the reset pin: the firmware restarts (no session, no pulses: the servo is limp)."""
        self.mega.reset()
        self.mode = proto.Mode.IDLE
        self._tx.reset_sequence()

    # ---- records ---------------------------------------------------------------------------------

    @property
    def pulses(self) -> np.ndarray:
        """Every servo pulse so far (``PULSE_DTYPE``; ``record=True`` only)."""
        if len(self._pulses) > 1:
            self._pulses = [np.concatenate(self._pulses)]
        return self._pulses[0] if self._pulses else np.zeros(0, PULSE_DTYPE)

    def pulse_angles(self, pulses: np.ndarray | None = None) -> np.ndarray:
        """The servo angle (deg) each pulse commands, by the servo's pulse widths."""
        p = self.pulses if pulses is None else pulses
        us0, us180 = self.servo_us
        return (p["width"] / CYCLES_PER_US - us0) * 180.0 / (us180 - us0)

    def edges(self) -> np.ndarray:
        """Every timing-pin edge so far (``EDGE_DTYPE``; ``record=True`` only)."""
        if len(self._edges) > 1:
            self._edges = [np.concatenate(self._edges)]
        return self._edges[0] if self._edges else np.zeros(0, EDGE_DTYPE)

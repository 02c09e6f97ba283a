"""A virtual gripper board on a pseudo-terminal: the firmware's protocol over the simulated rig.

``python -m tuners.rig.virtual [--plant test2] [--disturbance actual] [--speed 1.0]``
opens a pseudo-terminal, prints its path and then behaves like the Arduino Mega running
``firmware/gripper``: the same frames, modes, watchdog and telemetry, with the simulated actual
gripper behind it. Every host tool takes the printed path as its ``--port``.

Inside, three parts mirror the real rig:

* :class:`~gripper_env.hardware.twin.firmware.Firmware`, the board's state machine (the Python twin
  of ``firmware/gripper/gripper_device.h``, PID included), ticked every 1 ms of device time;
* :class:`~gripper_env.hardware.twin.rig.VirtualRig`, the servo, jaw and potentiometer: the
  project's one simulation core in open loop, driven by the firmware's servo command one
  physics step per tick, whose measured angle is reported as 10-bit ADC counts
  (:mod:`gripper_env.hardware.twin.rig`, with :class:`~gripper_env.hardware.twin.rig.
  TwinBoard`, the twin wired to the rig);
* the serial line: the firmware's 512-byte transmit queue drained at 1 Mbaud (100 bytes per
  tick) into the pty, the host's bytes fed to the firmware as they arrive.

Device time runs at ``speed`` times wall-clock time. At ``0`` (``max``) it runs as fast as the
CPU goes, paced by an active host: in an active mode it runs at most 200 ms of device time past
the host's last frame, then waits up to 1 s of wall time for the next one, so a busy host does
not trip the watchdog but a silent one still does. Ticks that start more than
250 us late in device time are flagged OVERRUN, as on the board.

:class:`VirtualDevice` is usable in-process (tests, notebooks) with fault-injection hooks:
garbage bytes, dropped, corrupted or truncated frames, a silent transmit line, answers delivered
late (a board slower than the host waits), the board's thread left waiting by a busy machine,
host frames lost on the way to the board, a reset mid-run and a vanishing port. Its command line
is :mod:`tuners.rig.virtual`.

Examples
--------
>>> with VirtualDevice("test2", "ideal", speed=0) as vd:  # doctest: +SKIP
...     print(vd.path)
/dev/pts/7
"""

from __future__ import annotations

import collections
import os
import select
import threading
import time
from typing import TYPE_CHECKING

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.pty import PtyDevice, PtyEndpoint, write_pending
from gripper_env.hardware.twin.firmware import UART_BYTES_PER_TICK
from gripper_env.hardware.twin.firmware_config import TICK_PERIOD_US
from gripper_env.hardware.twin.rig import VIRTUAL_DEVICE_ID, TwinBoard, VirtualRig

if TYPE_CHECKING:
    from gripper_env.hardware.emulator.board import EmulatedBoard

__all__ = ["VirtualDevice"]

_OUT_HIGH_WATER = 4096  # bytes waiting for the pty before the UART stops draining the queue
_MAX_TICKS_PER_PASS = 20  # the loop looks at the host's bytes at least every 20 ticks
_MAX_AHEAD_US = 200_000  # at speed 0, device time runs at most this far past the last host frame
#: At a real-time speed, a board thread that the machine left waiting (a busy machine) runs at
#: most this much device time late, in a burst, to catch up; beyond it, device time slips
#: behind the wall clock instead (:meth:`VirtualDevice.due_ticks`).
MAX_CATCH_UP_S = 0.1


class VirtualDevice(PtyDevice):
    """The virtual board on a pseudo-terminal, run by a background thread.

    Parameters
    ----------
    plant, disturbance : str
        The simulated rig (see :class:`~gripper_env.hardware.twin.rig.VirtualRig`).
    speed : float
        Device time per wall-clock time; ``0`` runs as fast as possible.
    seed : int
        Noise seed of the rig.
    device_id : int, optional
        Board id reported in INFO (default ``"VIRT"``, or ``"EMUL"`` for an image).
    y0_deg : float
        Jaw angle at power-on (deg).
    image : path, optional
        Run this compiled firmware image under simavr
        (:class:`~gripper_env.hardware.emulator.board.EmulatedBoard`) instead of the Python twin;
        its
        INFO reports the EEPROM id ``device_id``.
    harness : path, optional
        The simavr harness library for ``image`` (default: see
        :class:`~gripper_env.hardware.emulator.mega2560.Mega2560`).

    Attributes
    ----------
    board : TwinBoard or EmulatedBoard
        What runs behind the pty.
    firmware : Firmware or None
        The twin's state machine (inspect it in tests; it is driven by the thread); ``None`` for
        the emulated image.
    rig : VirtualRig
        The simulated gripper.
    ticks : int
        Milliseconds of device time run so far.
    """

    def __init__(
        self,
        plant: str = "test2",
        disturbance: str = "actual",
        *,
        speed: float = 1.0,
        seed: int = 0,
        device_id: int | None = None,
        y0_deg: float = 92.0,
        image: str | os.PathLike[str] | None = None,
        harness: str | os.PathLike[str] | None = None,
    ) -> None:
        if not speed >= 0:
            raise ValueError(f"speed must be >= 0 (0 = as fast as possible), got {speed}")
        self.speed = float(speed)
        self.board: TwinBoard | EmulatedBoard
        if image is None:
            self.device_id = VIRTUAL_DEVICE_ID if device_id is None else device_id
            self.rig = VirtualRig(plant, disturbance, seed, y0_deg)
            self.board = TwinBoard(self.rig, self.device_id)
        else:
            from gripper_env.hardware.emulator.board import EmulatedBoard
            from gripper_env.hardware.emulator.mega2560 import EMULATED_DEVICE_ID

            self.device_id = EMULATED_DEVICE_ID if device_id is None else device_id
            device_id = self.device_id
            self.rig = VirtualRig(plant, disturbance, seed, y0_deg, pulse_train=True)
            self.board = EmulatedBoard(self.rig, image=image, harness=harness, device_id=device_id)
        self.firmware = self.board.firmware
        self.ticks = 0
        #: Wall time (s) by which device time fell behind the wall clock, the board's thread
        #: having waited longer than :data:`MAX_CATCH_UP_S` for the machine (:meth:`due_ticks`).
        self.slipped_s = 0.0
        self._t0 = time.perf_counter()
        self._stall_s = 0.0
        self.lock = threading.Lock()
        self._pty = PtyEndpoint("virtual device")
        self._out = bytearray()
        self._frame = bytearray()  # a device frame being assembled while faults are armed
        self._drop = self._corrupt = self._truncate = 0
        self._silent = False
        self._delays: collections.deque[float] = collections.deque()
        self._late: collections.deque[tuple[float, bytes]] = collections.deque()
        self._paced_since = 0.0
        self._garbage = bytearray()
        self._reset_before: int | None = None
        self._lose: dict[int, int] = {}  # host frames to lose on the way in, by message type
        self.host_frames_lost = 0
        self.resets = 0
        self.bytes_sent = self.bytes_received = 0

    # ---- lifecycle -----------------------------------------------------------------------------

    def start(self) -> VirtualDevice:
        """Open the pty and start the board's thread; returns ``self``."""
        # what ends the loop is kept in error, and raised in the thread too (its excepthook
        # reports it)
        self._pty.start(self._loop, name="virtual-gripper", reraise=True)
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread and close the pty (idempotent)."""
        self._pty.stop(timeout_s)
        close = getattr(self.board, "close", None)
        if close is not None and not self.running:
            close()

    def __enter__(self) -> VirtualDevice:
        return self if self._pty.started else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- fault injection -----------------------------------------------------------------------

    def inject_garbage(self, data: bytes) -> None:
        """Send ``data`` to the host between two frames (noise on the line)."""
        with self.lock:
            self._garbage += data

    def drop_frames(self, n: int = 1) -> None:
        """Lose the next ``n`` frames to the host (their sequence numbers are still used)."""
        with self.lock:
            self._drop += n

    def corrupt_frames(self, n: int = 1) -> None:
        """Flip a bit in each of the next ``n`` frames to the host (the host's CRC check fails)."""
        with self.lock:
            self._corrupt += n

    def truncate_frames(self, n: int = 1) -> None:
        """Cut each of the next ``n`` frames to the host down to its first two bytes."""
        with self.lock:
            self._truncate += n

    def lose_host_frames(self, message_type: int, n: int = 1) -> None:
        """Lose the next ``n`` host frames of ``message_type`` before they reach the board (line
        noise that destroys them; the board sees a gap in the host's sequence numbers). Replaces
        what was armed for that type; 0 disarms. :attr:`host_frames_lost` counts the frames
        lost so far."""
        with self.lock:
            if n > 0:
                self._lose[int(message_type)] = n
            else:
                self._lose.pop(int(message_type), None)

    def go_silent(self, silent: bool = True) -> None:
        """Stop (or resume) transmitting: the board runs and listens, the host hears nothing."""
        with self.lock:
            self._silent = silent

    def stall(self, seconds: float) -> None:
        """Leave the board's thread waiting ``seconds`` of wall time, once, as a busy machine
        does to any process (the host's bytes wait in the pty meanwhile)."""
        with self.lock:
            self._stall_s = float(seconds)

    def delay_frames(self, *seconds: float) -> None:
        """Deliver the board's next frames late, the k-th by ``seconds[k]`` of wall time (the
        line stays first in, first out: a frame never overtakes a delayed one). A board or a
        USB bridge that answers after the host's timeout, as on a busy machine."""
        with self.lock:
            self._delays.extend(max(0.0, float(s)) for s in seconds)

    def reset(self) -> None:
        """Reset the board mid-run: the firmware restarts (no session, servo limp)."""
        with self.lock:
            self._reset_board()

    def reset_before(self, message_type: int) -> None:
        """Reset the board just before the next host frame of ``message_type`` reaches it (for
        example ``proto.Configure.TYPE``: a reset that lands while the host uploads a
        configuration). Fires once; :attr:`resets` counts the resets done."""
        with self.lock:
            self._reset_before = int(message_type)

    def _reset_board(self) -> None:
        self.board.reset(self._now_us())
        self._out.clear()
        self._frame.clear()
        self.resets += 1

    def vanish(self) -> None:
        """The USB cable is pulled: the pty closes under the host and the board stops."""
        self._pty.stop(5.0)

    # ---- the board's loop ----------------------------------------------------------------------

    def _now_us(self) -> int:
        return (self.ticks * TICK_PERIOD_US) & 0xFFFFFFFF

    def _loop(self, master: int, wake: int) -> None:
        """Run the board until stopped (the thread's body; see :class:`PtyEndpoint`)."""
        board = self.board
        ticks_per_s = self.speed * 1e6 / TICK_PERIOD_US
        self._t0 = time.perf_counter()
        while not self._pty.stopping.is_set():
            if self._stall_s:
                stall, self._stall_s = self._stall_s, 0.0
                time.sleep(stall)
            if ticks_per_s > 0:
                behind = self.due_ticks(time.perf_counter())
                if behind < 1.0:
                    wait = (1.0 - behind) / ticks_per_s
                    self._read_input(master, wake, min(wait, 0.05))
                    continue
                n = min(int(behind), _MAX_TICKS_PER_PASS)
            else:
                behind = 0.0
                n = _MAX_TICKS_PER_PASS
                # As fast as possible, but paced by an active host: at most 200 ms of device
                # time past its last frame, waiting up to 1 s of wall time for the next one
                # (a host silent for longer still meets the watchdog).
                ahead_us = (self._now_us() - board.last_rx_us) & 0xFFFFFFFF
                if board.active and ahead_us > _MAX_AHEAD_US:
                    if time.perf_counter() - self._paced_since < 1.0:
                        self._read_input(master, wake, 0.002)
                        continue
                else:
                    self._paced_since = time.perf_counter()
            self._read_input(master, wake, 0.0)
            with self.lock:
                for k in range(n):
                    now = (self.ticks * TICK_PERIOD_US) & 0xFFFFFFFF
                    # late by more than 250 us of device time: the twin flags an overrun
                    board.step(now, behind - k > 1.25)
                    self.ticks += 1
                    room = UART_BYTES_PER_TICK if len(self._out) < _OUT_HIGH_WATER else 0
                    data = board.uart_out(room)
                    if data:
                        self._emit(data)
            self._write_output(master)

    def due_ticks(self, now_s: float) -> float:
        """Ticks the board is behind the wall clock at ``now_s`` (``time.perf_counter``), at a
        real-time speed: at most :data:`MAX_CATCH_UP_S` of them.

        A real board runs its ticks when they are due whatever the host's machine does. This one
        runs on that machine: when the machine leaves its thread waiting, it runs the ticks it
        missed in a burst, faster than real time, and a burst of seconds would squeeze the
        host's replies out of seconds of device time: the board's watchdog fired on a host that
        was keeping up (``tuners.rig.record`` on a busy machine). So a longer wait makes device
        time slip behind the wall clock (:attr:`slipped_s`) rather than race to catch up.
        """
        ticks_per_s = self.speed * 1e6 / TICK_PERIOD_US
        behind = (now_s - self._t0) * ticks_per_s - self.ticks
        most = MAX_CATCH_UP_S * ticks_per_s
        if behind > most:
            slip = (behind - most) / ticks_per_s
            self._t0 += slip
            self.slipped_s += slip
            behind = most
        return behind

    def _read_input(self, master: int, wake: int, timeout_s: float) -> None:
        # A board whose line is full takes nothing more: the host's bytes wait in the pty, and
        # its writes block once that is full too (flow control, as a USB bridge does), instead
        # of the emulated line overflowing; the ticks drain it meanwhile.
        room = self.board.rx_room() if hasattr(self.board, "rx_room") else 4096
        # the wake pipe ends the wait when stop() or vanish() is called
        readable, _, _ = select.select([master, wake] if room > 0 else [wake], [], [], timeout_s)
        if master not in readable:
            return
        try:
            data = os.read(master, min(4096, room))
        except BlockingIOError:
            return
        except OSError:  # EIO: no process holds the slave side (cannot happen while we do)
            return
        if data:
            self.bytes_received += len(data)
            with self.lock:
                if self._reset_before is not None and self._carries(data, self._reset_before):
                    self._reset_before = None
                    self._reset_board()
                if self._lose:
                    data = self._lose_frames(data)
                self.board.receive(data, self._now_us())

    @staticmethod
    def _carries(data: bytes, message_type: int) -> bool:
        """``data`` holds a whole host frame of ``message_type``."""
        for chunk in data.split(b"\x00")[:-1]:
            try:
                raw = proto.cobs_decode(chunk)
            except proto.CobsError:
                continue
            if len(raw) >= 2 and raw[1] == message_type:
                return True
        return False

    def _lose_frames(self, data: bytes) -> bytes:
        """``data`` without the whole host frames :meth:`lose_host_frames` armed."""
        chunks = data.split(b"\x00")
        kept = []
        for k, chunk in enumerate(chunks):
            whole = k < len(chunks) - 1  # ended by a delimiter in this read
            type_id = -1
            if whole and chunk:
                try:
                    raw = proto.cobs_decode(chunk)
                    type_id = raw[1] if len(raw) >= 2 else -1
                except proto.CobsError:
                    pass
            if self._lose.get(type_id, 0) > 0:
                self._lose[type_id] -= 1
                if not self._lose[type_id]:
                    del self._lose[type_id]
                self.host_frames_lost += 1
                continue
            kept.append(chunk + (b"\x00" if whole else b""))
        return b"".join(kept)

    def _emit(self, data: bytes) -> None:
        """Pass bytes the UART sent through the armed faults to the line."""
        if self._silent:
            return
        if self._delays or self._late:  # delayed frames, and whatever follows them
            release = time.perf_counter() + (self._delays[0] if self._delays else 0.0)
            if self._late:
                release = max(release, self._late[-1][0])
            for _ in range(min(data.count(0), len(self._delays))):
                self._delays.popleft()
            self._late.append((release, bytes(data)))
            return
        if self._garbage:
            self._out += self._garbage
            self._garbage.clear()
        if not (self._drop or self._corrupt or self._truncate or self._frame):
            self._out += data
            return
        start = 0
        while start < len(data):
            end = data.find(0, start)
            if end < 0:
                self._frame += data[start:]
                return
            frame = bytes(self._frame + data[start : end + 1])
            self._frame.clear()
            start = end + 1
            if self._drop:
                self._drop -= 1
                continue
            if self._corrupt:
                self._corrupt -= 1
                raw = bytearray(proto.cobs_decode(frame[:-1]))
                raw[-1] ^= 0x01  # a flipped CRC bit: valid COBS, failing CRC
                frame = proto.cobs_encode(bytes(raw)) + b"\x00"
            elif self._truncate:
                self._truncate -= 1
                decoded = proto.cobs_decode(frame[:-1])
                frame = proto.cobs_encode(decoded[:3]) + b"\x00"  # shorter than seq+type+crc
            self._out += frame

    def _write_output(self, master: int) -> None:
        # Under the lock: reset() clears the output from another thread, and a bytearray cannot
        # be resized while os.write holds it (BufferError), nor trimmed by what another wrote.
        with self.lock:
            if self._garbage:
                if not self._silent:
                    self._out += self._garbage
                self._garbage.clear()
            now = time.perf_counter()
            while self._late and self._late[0][0] <= now:
                self._out += self._late.popleft()[1]
            self.bytes_sent += write_pending(master, self._out)

    # ---- introspection for tests ---------------------------------------------------------------

    @property
    def device_time_s(self) -> float:
        """Device time since start (s)."""
        return self.ticks * TICK_PERIOD_US / 1e6

    def wait_ticks(self, n: int, timeout_s: float = 10.0) -> bool:
        """Block until ``n`` more ticks have run (False on timeout or if the thread ended)."""
        target = self.ticks + n
        deadline = time.monotonic() + timeout_s
        while self.ticks < target:
            if time.monotonic() > deadline or not self.running:
                return False
            time.sleep(0.001)
        return True

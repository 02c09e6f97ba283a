"""A virtual gripper board on a pseudo-terminal: the firmware's protocol over the simulated rig.

``python -m gripper_env.hardware.virtual [--plant test2] [--disturbance actual] [--speed 1.0]``
opens a pseudo-terminal, prints its path and then behaves like the Arduino Mega running
``firmware/gripper``: the same frames, modes, watchdog and telemetry, with the simulated actual
gripper behind it. Every host tool takes the printed path as its ``--port``.

Inside, three parts mirror the real rig:

* :class:`~gripper_env.hardware.firmware.Firmware`, the board's state machine (the Python twin
  of ``firmware/gripper/gripper_device.h``, PID included), ticked every 1 ms of device time;
* :class:`VirtualRig`, the servo, jaw and potentiometer: the project's one simulation core
  (:class:`~gripper_env.sim.BatchSimulator`) in open loop, driven by the firmware's servo
  command one physics step per tick, whose measured angle is reported as 10-bit ADC counts;
* the serial line: the firmware's 512-byte transmit queue drained at 1 Mbaud (100 bytes per
  tick) into the pty, the host's bytes fed to the firmware as they arrive.

Device time runs at ``speed`` times wall-clock time. At ``0`` (``max``) it runs as fast as the
CPU goes, paced by an active host: in an active mode it runs at most 200 ms of device time past
the host's last frame, then waits up to 1 s of wall time for the next one, so a busy host does
not trip the watchdog but a silent one still does. Ticks that start more than
250 us late in device time are flagged OVERRUN, as on the board.

The one difference from the board's timing: the firmware reads the measurement taken at the
end of the previous physics step (the simulation core measures before it applies a command), a
1 ms sensor delay that the closed loop hardly notices (the plants' fastest pole is 96 rad/s).

:class:`VirtualDevice` is usable in-process (tests, notebooks) with fault-injection hooks:
garbage bytes, dropped, corrupted or truncated frames, a silent transmit line, a reset mid-run
and a vanishing port.

Examples
--------
>>> with VirtualDevice("test2", "ideal", speed=0) as vd:  # doctest: +SKIP
...     print(vd.path)
/dev/pts/7
"""

from __future__ import annotations

import argparse
import os
import select
import signal
import sys
import threading
import time
import tty
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.disturbances import load_disturbance
from gripper_env.hardware import protocol as proto
from gripper_env.hardware.firmware import (
    ADC_MAX_COUNT,
    CAL_ANGLE_HI_DEG,
    CAL_ANGLE_LO_DEG,
    TICK_PERIOD_US,
    UART_BYTES_PER_TICK,
    Firmware,
)
from gripper_env.pid import pid_update
from gripper_env.plants import load_plant
from gripper_env.sim import BatchSimulator

if TYPE_CHECKING:
    from gripper_env.hardware.emulator import EmulatedBoard

__all__ = ["TwinBoard", "VirtualDevice", "VirtualRig", "main", "parse_speed"]

VIRTUAL_DEVICE_ID = 0x56495254  # "VIRT"
_DEFAULT_ADC_RANGE_DEG = (0.0, 270.0)  # a 270-degree pot on the 10-bit ADC
_OUT_HIGH_WATER = 4096  # bytes waiting for the pty before the UART stops draining the queue
_MAX_TICKS_PER_PASS = 20  # the loop looks at the host's bytes at least every 20 ticks
_MAX_AHEAD_US = 200_000  # at speed 0, device time runs at most this far past the last host frame


class VirtualRig:
    """The servo, jaw and potentiometer behind the virtual board.

    Parameters
    ----------
    plant : str or path
        Plant name or YAML file (the servo's transfer function).
    disturbance : str or path
        Actual-gripper preset (command path, friction, stops, sensor noise and ADC).
    seed : int
        Noise seed.
    y0_deg : float
        Jaw angle at power-on (deg).
    pulse_train : bool
        The servo is driven by a real pulse train (the emulated firmware's): the preset's command
        quantisation and refresh are dropped, since the pulses carry their own resolution and
        50 Hz timing. The command range, friction, stops and sensor stay.
    """

    def __init__(
        self,
        plant: str = "test2",
        disturbance: str = "actual",
        seed: int = 0,
        y0_deg: float = 92.0,
        *,
        pulse_train: bool = False,
    ) -> None:
        self.plant = load_plant(plant)
        self.disturbance = load_disturbance(disturbance)
        self.pulse_train = pulse_train
        if pulse_train:
            self.disturbance = self.disturbance.with_overrides(
                {"command": {"quantization": "none", "refresh_period_s": 0.0}}
            )
        sensor = self.disturbance.sensor
        delay = max(1, round(sensor.delay_s / self.plant.dt_s))
        self.sim = BatchSimulator(self.plant, delay_capacity=delay)
        self.sim.configure(None, self.disturbance)
        self.sim.reset(y0_deg, seed)
        lo, hi = sensor.adc_range_deg if sensor.adc_bits else _DEFAULT_ADC_RANGE_DEG
        self.adc_lo_deg = lo
        self.deg_per_count = (hi - lo) / ADC_MAX_COUNT
        self._command = np.zeros(1)
        self._out = tuple(np.empty((1, 1)) for _ in range(4))
        # load the compiled kernels now, not at the first tick (a zero-step advance is a no-op)
        self.sim.advance(0, self._command, 0, tuple(np.empty((1, 0)) for _ in range(4)))
        pid_update(0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 1e-3, 0.0, 1.0, 1, 1.0, 1.0, 0, np.zeros(2))
        self.adc = self.counts(y0_deg)
        self.position_deg = float(y0_deg)

    def counts(self, angle_deg: float) -> int:
        """ADC reading (0..1023) for a measured angle (deg)."""
        code = int(np.floor((angle_deg - self.adc_lo_deg) / self.deg_per_count + 0.5))
        return min(max(code, 0), ADC_MAX_COUNT)

    @property
    def true_calibration(self) -> tuple[float, float]:
        """ADC counts (fractional) at exactly 21 and 92 deg: what a perfect calibration finds."""
        return tuple(  # type: ignore[return-value]
            (a - self.adc_lo_deg) / self.deg_per_count for a in (CAL_ANGLE_LO_DEG, CAL_ANGLE_HI_DEG)
        )

    def step(self, command_deg: float | None) -> int:
        """Advance one physics step with the servo command (deg), ``None`` while the servo gets
        no pulses (limp: it holds where it is); return the new ADC reading."""
        self._command[0] = self.position_deg if command_deg is None else command_deg
        _r, _u, y, y_true = self.sim.advance(1, self._command, 0, self._out)
        self.position_deg = float(y_true[0, 0])
        self.adc = self.counts(float(y[0, 0]))
        return self.adc


class TwinBoard:
    """The Python twin of the firmware wired to a rig: the board :class:`VirtualDevice` runs by
    default (the other is :class:`~gripper_env.hardware.emulator.EmulatedBoard`, the real image).

    Parameters
    ----------
    rig : VirtualRig
        The simulated gripper.
    device_id : int
        Board id reported in INFO.

    Attributes
    ----------
    firmware : Firmware
        The board's state machine.
    """

    def __init__(self, rig: VirtualRig, device_id: int = VIRTUAL_DEVICE_ID) -> None:
        self.rig = rig
        self.device_id = device_id
        self.firmware = Firmware(device_id, 0)
        self.firmware.tx += b"\x00"  # the sketch's boot delimiter (gripper.ino, setup)

    @property
    def active(self) -> bool:
        """In an active mode (open or closed loop)."""
        return self.firmware.mode != 0

    @property
    def last_rx_us(self) -> int:
        """Device time (us) of the last valid host frame."""
        return self.firmware.last_rx_us

    def receive(self, data: bytes, now_us: int) -> None:
        """Bytes from the host at device time ``now_us``."""
        self.firmware.receive(data, now_us)

    def step(self, now_us: int, overrun: bool = False) -> None:
        """One control tick with the rig's reading, then one physics step with its command."""
        fw = self.firmware
        fw.tick(now_us, self.rig.adc, overrun)
        self.rig.step(fw.command if fw.servo_on else None)

    def uart_out(self, max_bytes: int) -> bytes:
        """At most ``max_bytes`` of the transmit queue, as the UART sends them in one tick."""
        return self.firmware.uart_drain(max_bytes) if self.firmware.tx and max_bytes else b""

    def reset(self, now_us: int) -> None:
        """The board restarts (no session, servo limp) and sends its boot delimiter."""
        self.firmware.begin(self.device_id, now_us)
        self.firmware.tx += b"\x00"


class VirtualDevice:
    """The virtual board on a pseudo-terminal, run by a background thread.

    Parameters
    ----------
    plant, disturbance : str
        The simulated rig (see :class:`VirtualRig`).
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
        (:class:`~gripper_env.hardware.emulator.EmulatedBoard`) instead of the Python twin; its
        INFO reports the EEPROM id ``device_id``.
    harness : path, optional
        The simavr harness library for ``image`` (default: see
        :class:`~gripper_env.hardware.emulator.Mega2560`).

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
            from gripper_env.hardware.emulator import EMULATED_DEVICE_ID, EmulatedBoard

            self.device_id = EMULATED_DEVICE_ID if device_id is None else device_id
            device_id = self.device_id
            self.rig = VirtualRig(plant, disturbance, seed, y0_deg, pulse_train=True)
            self.board = EmulatedBoard(self.rig, image=image, harness=harness, device_id=device_id)
        self.firmware = self.board.firmware
        self.ticks = 0
        self.lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._path = ""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._out = bytearray()
        self._frame = bytearray()  # a device frame being assembled while faults are armed
        self._drop = self._corrupt = self._truncate = 0
        self._silent = False
        self._paced_since = 0.0
        self._garbage = bytearray()
        self.error: BaseException | None = None
        self.bytes_sent = self.bytes_received = 0

    # ---- lifecycle -----------------------------------------------------------------------------

    @property
    def path(self) -> str:
        """Path of the pseudo-terminal the host opens (``/dev/pts/N``)."""
        if not self._path:
            raise RuntimeError("the virtual device is not started")
        return self._path

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> VirtualDevice:
        """Open the pty and start the board's thread; returns ``self``."""
        if self._thread is not None:
            raise RuntimeError("the virtual device was already started")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass unchanged
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._path = os.ttyname(slave)
        self._thread = threading.Thread(target=self._run, name="virtual-gripper", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._close_fds()
        close = getattr(self.board, "close", None)
        if close is not None and not self.running:
            close()

    def __enter__(self) -> VirtualDevice:
        return self.start() if self._thread is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _close_fds(self) -> None:
        for name in ("_master", "_slave"):
            fd = getattr(self, name)
            if fd is not None:
                setattr(self, name, None)
                try:
                    os.close(fd)
                except OSError:
                    pass

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

    def go_silent(self, silent: bool = True) -> None:
        """Stop (or resume) transmitting: the board runs and listens, the host hears nothing."""
        with self.lock:
            self._silent = silent

    def reset(self) -> None:
        """Reset the board mid-run: the firmware restarts (no session, servo limp)."""
        with self.lock:
            self.board.reset(self._now_us())
            self._out.clear()
            self._frame.clear()

    def vanish(self) -> None:
        """The USB cable is pulled: the pty closes under the host and the board stops."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._close_fds()

    # ---- the board's loop ----------------------------------------------------------------------

    def _now_us(self) -> int:
        return (self.ticks * TICK_PERIOD_US) & 0xFFFFFFFF

    def _run(self) -> None:
        try:
            self._loop()
        except OSError as exc:  # the pty went away under us (vanish, or closed by stop)
            if not self._stop.is_set():
                self.error = exc
        except BaseException as exc:  # kept for the owner to inspect, then re-raised
            self.error = exc
            raise

    def _loop(self) -> None:
        master = self._master
        assert master is not None
        board = self.board
        ticks_per_s = self.speed * 1e6 / TICK_PERIOD_US
        t0 = time.perf_counter()
        while not self._stop.is_set():
            if ticks_per_s > 0:
                behind = (time.perf_counter() - t0) * ticks_per_s - self.ticks
                if behind < 1.0:
                    wait = (1.0 - behind) / ticks_per_s
                    self._read_input(master, min(wait, 0.05))
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
                        self._read_input(master, 0.002)
                        continue
                else:
                    self._paced_since = time.perf_counter()
            self._read_input(master, 0.0)
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

    def _read_input(self, master: int, timeout_s: float) -> None:
        readable, _, _ = select.select([master], [], [], timeout_s)
        if not readable:
            return
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError:  # EIO: no process holds the slave side (cannot happen while we do)
            return
        if data:
            self.bytes_received += len(data)
            with self.lock:
                self.board.receive(data, self._now_us())

    def _emit(self, data: bytes) -> None:
        """Pass bytes the UART sent through the armed faults to the line."""
        if self._silent:
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
                raw = proto.cobs_decode(frame[:-1])
                frame = proto.cobs_encode(raw[:3]) + b"\x00"  # shorter than seq+type+crc
            self._out += frame

    def _write_output(self, master: int) -> None:
        # Under the lock: reset() clears the output from another thread, and a bytearray cannot
        # be resized while os.write holds it (BufferError), nor trimmed by what another wrote.
        with self.lock:
            if self._garbage:
                if not self._silent:
                    self._out += self._garbage
                self._garbage.clear()
            if not self._out:
                return
            try:
                written = os.write(master, self._out)  # non-blocking: never waits
            except BlockingIOError:
                return
            self.bytes_sent += written
            del self._out[:written]

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


# ---- command line -------------------------------------------------------------------------------


def parse_speed(text: str) -> float:
    """``--speed`` value: a factor >= 0, or ``max`` (same as 0: as fast as possible)."""
    if text.strip().lower() == "max":
        return 0.0
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"speed must be a number >= 0 or 'max', got {text!r}"
        ) from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"speed must be a finite number >= 0 or 'max', got {text}")
    return value


def _parser(emulated: bool = False) -> argparse.ArgumentParser:
    if emulated:
        prog = "python -m gripper_env.hardware.emulator"
        what = (
            "Run the compiled Mega 2560 firmware under simavr on a pseudo-terminal, over the "
            "simulated actual gripper (the firmware's own servo pulses drive it, the ADC reads it)."
            " Builds the image and the harness with the project's scripts when missing."
        )
    else:
        prog = "python -m gripper_env.hardware.virtual"
        what = (
            "Run a virtual gripper board on a pseudo-terminal: the firmware's protocol, modes and "
            "watchdog (its Python twin) over the simulated actual gripper."
        )
    parser = argparse.ArgumentParser(
        prog=prog,
        description=what + " Prints the pty path; pass it as --port to the host tools (with "
        "--boot-wait 0: the board boots at once). Stops on Ctrl-C or SIGTERM.",
    )
    parser.add_argument("--plant", default="test2", help="plant name or YAML file (default: test2)")
    parser.add_argument(
        "--disturbance",
        default="actual",
        help="actual-gripper preset name or YAML file (default: actual)",
    )
    parser.add_argument(
        "--speed",
        type=parse_speed,
        default=1.0,
        help="device time per wall-clock time: 1 = real time, 2 = twice as fast, "
        "0 or 'max' = as fast as possible, paced by an active host (default: 1)",
    )
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed (default: 0)")
    parser.add_argument(
        "--y0",
        type=float,
        default=92.0,
        help="jaw angle at power-on, deg (default: 92, open)",
    )
    parser.add_argument(
        "--link",
        default=None,
        help="also make a symbolic link to the pty at this path (removed on exit)",
    )
    if emulated:
        parser.add_argument(
            "--image",
            default=None,
            metavar="ELF",
            help="firmware image to run (default: firmware/build-mega/gripper.elf, built by "
            "firmware/build.sh when missing)",
        )
        parser.add_argument(
            "--rebuild",
            action="store_true",
            help="rebuild the default image and the harness before starting",
        )
    else:
        parser.add_argument(
            "--image",
            default=None,
            metavar="ELF",
            help="run this compiled firmware image under simavr instead of the Python twin "
            "(see python -m gripper_env.hardware.emulator)",
        )
    return parser


def main(argv: Sequence[str] | None = None, emulated: bool = False) -> int:
    """Entry point of ``python -m gripper_env.hardware.virtual`` (and, with ``emulated``, of
    ``python -m gripper_env.hardware.emulator``)."""
    parser = _parser(emulated)
    args = parser.parse_args(argv)
    try:
        if not 0.0 <= args.y0 <= 180.0:
            raise ValueError(f"--y0 must be an angle in [0, 180] deg, got {args.y0}")
        image = args.image
        if emulated:
            from gripper_env.hardware.emulator import ensure_built

            image, _harness = ensure_built(args.image, rebuild=args.rebuild)
        device = VirtualDevice(
            args.plant, args.disturbance, speed=args.speed, seed=args.seed, y0_deg=args.y0,
            image=image,
        )  # fmt: skip
    except (ValueError, OSError, RuntimeError) as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    device.start()
    link = None
    try:
        if args.link:
            link = os.path.abspath(args.link)
            if os.path.islink(link):
                os.unlink(link)
            os.symlink(device.path, link)
        speed = "max" if args.speed == 0 else f"{args.speed:g}x"
        board = f"firmware image {image}" if image else "the firmware's Python twin"
        print(device.path, flush=True)
        print(
            f"virtual gripper ({board}): plant {args.plant}, disturbance {args.disturbance}, "
            f"speed {speed}" + (f", linked at {link}" if link else "") + "; Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        while not stop.wait(0.2):
            if not device.running:
                break
    except OSError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    finally:
        device.stop()
        if link and os.path.islink(link):
            os.unlink(link)
    if device.error is not None:
        print(f"{parser.prog}: error: the board stopped: {device.error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

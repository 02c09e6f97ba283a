"""The compiled Mega 2560 firmware in the loop: the real image under simavr, on emulated time.

Two layers:

* :class:`Mega2560` loads ``firmware/build-mega/gripper.elf`` (what ``firmware/build.sh``
  produces) into an emulated ATmega2560 at 16 MHz through the harness
  ``firmware/emulator/board.c`` (a small C library over Debian's ``libsimavr``, loaded with
  :mod:`ctypes`). It is the rig's view of the board: bytes on UART0 (paced at the line rate),
  the voltage on A0 in ADC counts, the servo pulses Timer1 drives on pin 11, edges of the
  firmware's timing pins (13: control path, 12: telemetry frame), the stack's low-water mark.
* :class:`EmulatedBoard` wires it to the simulated gripper (:class:`~gripper_env.hardware.
  virtual.VirtualRig`, the project's simulation core) one millisecond at a time: the rig's
  potentiometer reading goes onto A0, the CPU runs, each servo pulse's width becomes the servo's
  angle (the firmware's pulse conversion inverted) when the pulse ends, and the rig takes one
  physics step. :class:`~gripper_env.hardware.virtual.VirtualDevice` puts it behind a pty, so the
  host tools talk to the real firmware exactly as to a board: ``python -m
  gripper_env.hardware.emulator`` prints the port.

Emulated time (CPU cycles at 16 MHz) is the only clock: the same bytes at the same emulated
instants give the same pulses, whatever the host's speed.

The servo of the emulated rig gets the firmware's real command path, so the rig's preset keeps
its friction, stops and sensor but not its command quantisation and refresh: the pulse has the
timer's 0.5 us resolution (about 0.05 deg) and arrives every 20 ms at the timer's own phase.

Both the image and the harness are built from the project's own scripts (``firmware/build.sh``,
``firmware/emulator/build.sh``); :func:`build_image`, :func:`build_harness` and
:func:`ensure_built` call them.

Examples
--------
>>> from gripper_env.hardware.virtual import VirtualRig
>>> board = EmulatedBoard(VirtualRig("test2", "actual", pulse_train=True))  # doctest: +SKIP
>>> board.run(50)  # 50 ms: the firmware boots  # doctest: +SKIP
"""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.hardware import protocol as proto

if TYPE_CHECKING:
    from gripper_env.hardware.virtual import VirtualRig

__all__ = [
    "CPU_HZ",
    "CYCLES_PER_MS",
    "EDGE_DTYPE",
    "PULSE_DTYPE",
    "TX_DTYPE",
    "EmulatedBoard",
    "EmulatorUnavailable",
    "Mega2560",
    "build_harness",
    "build_image",
    "emulator_missing",
    "ensure_built",
    "main",
]

CPU_HZ = 16_000_000  # the Mega 2560's crystal
CYCLES_PER_US = CPU_HZ // 1_000_000
CYCLES_PER_MS = CPU_HZ // 1000
REPO = Path(__file__).resolve().parents[2]
FIRMWARE_DIR = REPO / "firmware"
DEFAULT_IMAGE = FIRMWARE_DIR / "build-mega" / "gripper.elf"
DEFAULT_HARNESS = FIRMWARE_DIR / "build-emulator" / "libgripper_board.so"
ABI_VERSION = 1  # GB_ABI_VERSION in board.h
EMULATED_DEVICE_ID = 0x454D554C  # "EMUL" in EEPROM bytes 0-3
SERVO_US = (544, 2400)  # the emulated servo's pulse widths at 0 and 180 deg (hobby-servo standard)
SERVO_LIMP_MS = 25  # a servo that sees no pulse for this long stops driving (one frame lost)
TIMING_PINS = (("B", 7), ("B", 6))  # firmware marks: control path (pin 13), telemetry (pin 12)

PULSE_DTYPE = np.dtype(
    [("start", "<u8"), ("width", "<u4"), ("ocr", "<u2"), ("top", "<u2")], align=True
)
EDGE_DTYPE = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1")], align=True)
TX_DTYPE = np.dtype([("cycle", "<u8"), ("byte", "u1")], align=True)

# simavr's cpu states (sim_avr.h)
CPU_STATES = ("limbo", "stopped", "running", "sleeping", "step", "step_done", "done", "crashed")


class EmulatorUnavailable(RuntimeError):
    """The emulator cannot run here (a package, the image or the harness is missing)."""


class _Stats(ctypes.Structure):
    _fields_ = [
        ("cycle", ctypes.c_uint64),
        ("instructions", ctypes.c_uint64),
        ("sleep_cycles", ctypes.c_uint64),
        ("rx_bytes", ctypes.c_uint64),
        ("tx_bytes", ctypes.c_uint64),
        ("rx_overruns", ctypes.c_uint32),
        ("rx_ignored", ctypes.c_uint32),
        ("resets", ctypes.c_uint32),
        ("pulses", ctypes.c_uint32),
        ("pulse_faults", ctypes.c_uint32),
        ("dropped", ctypes.c_uint32),
        ("log_errors", ctypes.c_uint32),
        ("cycles_per_byte", ctypes.c_uint32),
        ("sp_min", ctypes.c_uint16),
        ("ramend", ctypes.c_uint16),
        ("state", ctypes.c_int32),
        ("timer1_mode", ctypes.c_int32),
    ]


class _Pulse(ctypes.Structure):
    _fields_ = [
        ("start", ctypes.c_uint64),
        ("width", ctypes.c_uint32),
        ("ocr", ctypes.c_uint16),
        ("top", ctypes.c_uint16),
    ]


def emulator_missing() -> str | None:
    """Why the emulator cannot be built here (a missing tool or package), or ``None``."""
    needs = {
        "avr-g++": "gcc-avr",
        "avr-size": "binutils-avr",
        "make": "make",
        "gcc": "gcc",
        "pkg-config": "pkg-config",
    }
    missing = [pkg for tool, pkg in needs.items() if shutil.which(tool) is None]
    if not Path("/usr/share/arduino/Arduino.mk").exists():
        missing += ["arduino-mk", "arduino-core-avr"]
    if shutil.which("pkg-config"):
        found = subprocess.run(["pkg-config", "--exists", "simavr"], check=False)
        has_simavr = found.returncode == 0
    else:
        has_simavr = Path("/usr/include/simavr/sim_avr.h").exists()
    if not has_simavr:
        missing += ["libsimavr-dev"]
    if not Path("/usr/include/libelf.h").exists() and not Path("/usr/include/gelf.h").exists():
        missing += ["libelf-dev"]
    if missing:
        return "missing Debian packages: " + " ".join(sorted(set(missing)))
    return None


def _run_script(cmd: list[str], what: str) -> str:
    result = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    if result.returncode != 0:
        raise EmulatorUnavailable(
            f"{what} failed ({' '.join(cmd)}):\n{result.stdout[-2000:]}{result.stderr[-2000:]}"
        )
    return result.stdout


def build_image(out_dir: str | os.PathLike[str] | None = None) -> Path:
    """Build the firmware with ``firmware/build.sh`` and return the ELF image's path.

    Parameters
    ----------
    out_dir : path, optional
        Build directory (default ``firmware/build-mega``); a separate one lets parallel test
        workers build without racing.
    """
    cmd = [str(FIRMWARE_DIR / "build.sh")]
    if out_dir is not None:
        cmd.append(str(Path(out_dir).resolve()))
    out = _run_script(cmd, "firmware build")
    elf = Path(out_dir).resolve() / "gripper.elf" if out_dir is not None else DEFAULT_IMAGE
    if not elf.exists():
        raise EmulatorUnavailable(f"firmware build wrote no {elf}:\n{out}")
    return elf


def build_harness(out_dir: str | os.PathLike[str] | None = None) -> Path:
    """Build the harness library with ``firmware/emulator/build.sh``; return its path."""
    cmd = [str(FIRMWARE_DIR / "emulator" / "build.sh")]
    if out_dir is not None:
        cmd.append(str(Path(out_dir).resolve()))
    return Path(_run_script(cmd, "emulator harness build").strip().splitlines()[-1])


def ensure_built(
    image: str | os.PathLike[str] | None = None, rebuild: bool = False
) -> tuple[Path, Path]:
    """The image and the harness library, built by the project's scripts when missing.

    Parameters
    ----------
    image : path, optional
        An image to use as it is; default ``firmware/build-mega/gripper.elf`` (built if missing
        or if ``rebuild``).
    rebuild : bool
        Rebuild the default image and the harness even if they exist.

    Raises
    ------
    EmulatorUnavailable
        A Debian package is missing (the message names it) or a build failed.
    """
    harness = Path(os.environ.get("GRIPPER_EMULATOR_LIB") or DEFAULT_HARNESS)
    if image is not None and not Path(image).exists():
        raise EmulatorUnavailable(f"no firmware image at {image}")
    need_image = image is None and (rebuild or not DEFAULT_IMAGE.exists())
    need_harness = rebuild or not harness.exists()
    if (need_image or need_harness) and not FIRMWARE_DIR.is_dir():
        # an installed wheel carries no firmware sources
        raise EmulatorUnavailable(
            f"cannot build the emulator: no firmware sources at {FIRMWARE_DIR} (they are not "
            "installed with the package); run it from a source checkout, or pass --image with "
            "a built image and set GRIPPER_EMULATOR_LIB to a built harness"
        )
    if need_image or need_harness:
        why = emulator_missing()
        if why:
            raise EmulatorUnavailable(
                f"cannot build the emulator: {why} (bash scripts/system-packages.sh installs them)"
            )
    if need_image:
        build_image()
    if need_harness:
        harness = build_harness(harness.parent)
    return (Path(image) if image is not None else DEFAULT_IMAGE), harness


def _load_library(path: Path) -> ctypes.CDLL:
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        raise EmulatorUnavailable(f"cannot load the emulator harness {path}: {exc}") from None
    if lib.gb_abi_version() != ABI_VERSION:
        raise EmulatorUnavailable(
            f"{path} is harness ABI {lib.gb_abi_version()}, this module needs {ABI_VERSION}: "
            "rebuild it with firmware/emulator/build.sh"
        )
    vp, u64, sz = ctypes.c_void_p, ctypes.c_uint64, ctypes.c_size_t
    signatures = {
        "gb_open": (vp, [ctypes.c_char_p, ctypes.c_uint32, ctypes.c_char_p, sz]),
        "gb_close": (None, [vp]),
        "gb_reset": (None, [vp]),
        "gb_run_until": (ctypes.c_int, [vp, u64]),
        "gb_cycle": (u64, [vp]),
        "gb_eeprom_write": (ctypes.c_int, [vp, ctypes.c_uint16, ctypes.c_char_p, ctypes.c_uint32]),
        "gb_set_adc_counts": (None, [vp, ctypes.c_int, ctypes.c_uint32]),
        "gb_rx_write": (sz, [vp, ctypes.c_char_p, sz]),
        "gb_rx_pending": (sz, [vp]),
        "gb_rx_last_cycle": (u64, [vp]),
        "gb_tx_read": (sz, [vp, vp, sz]),
        "gb_pulses_read": (sz, [vp, vp, sz]),
        "gb_last_pulse": (_Pulse, [vp]),
        "gb_watch_pin": (ctypes.c_int, [vp, ctypes.c_char, ctypes.c_int]),
        "gb_edges_read": (sz, [vp, vp, sz]),
        "gb_stats": (None, [vp, ctypes.POINTER(_Stats)]),
        "gb_reset_sp_min": (None, [vp]),
        "gb_profile": (ctypes.c_int, [vp, ctypes.c_int]),
        "gb_profile_read": (sz, [vp, vp, sz]),
        "gb_last_log": (ctypes.c_char_p, [vp]),
    }
    for name, (restype, argtypes) in signatures.items():
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes
    return lib


_LIBS: dict[Path, ctypes.CDLL] = {}


class Mega2560:
    """One emulated Mega 2560 running a firmware image (see the module docstring).

    Parameters
    ----------
    image : path, optional
        The ELF (or Intel hex) image; default ``firmware/build-mega/gripper.elf``.
    harness : path, optional
        The harness library; default ``firmware/build-emulator/libgripper_board.so``, or
        ``$GRIPPER_EMULATOR_LIB``.
    device_id : int
        Written to EEPROM bytes 0-3 (the firmware reports it in INFO).

    Raises
    ------
    EmulatorUnavailable
        The image or the harness is missing or cannot be loaded.
    """

    def __init__(
        self,
        image: str | os.PathLike[str] | None = None,
        harness: str | os.PathLike[str] | None = None,
        device_id: int = EMULATED_DEVICE_ID,
    ) -> None:
        self.image = Path(image) if image is not None else DEFAULT_IMAGE
        lib_path = Path(harness or os.environ.get("GRIPPER_EMULATOR_LIB") or DEFAULT_HARNESS)
        for path, what, script in (
            (self.image, "firmware image", "firmware/build.sh"),
            (lib_path, "emulator harness", "firmware/emulator/build.sh"),
        ):
            if not path.exists():
                raise EmulatorUnavailable(f"no {what} at {path}: build it with {script}")
        lib_path = lib_path.resolve()
        if lib_path not in _LIBS:
            _LIBS[lib_path] = _load_library(lib_path)
        self._lib = _LIBS[lib_path]
        err = ctypes.create_string_buffer(256)
        handle = self._lib.gb_open(str(self.image).encode(), CPU_HZ, err, len(err))
        if not handle:
            raise EmulatorUnavailable(f"cannot load {self.image}: {err.value.decode()}")
        self._h = handle
        self.device_id = device_id
        self._lib.gb_eeprom_write(self._handle, 0, device_id.to_bytes(4, "little"), 4)
        self._pulse_buf = np.zeros(256, PULSE_DTYPE)
        self._edge_buf = np.zeros(8192, EDGE_DTYPE)
        self._tx_buf = np.zeros(8192, TX_DTYPE)

    # ---- lifecycle -----------------------------------------------------------------------------

    @property
    def _handle(self) -> int:
        if not self._h:
            raise RuntimeError("the emulated Mega 2560 is closed")
        return self._h

    def close(self) -> None:
        """Free the emulated MCU (idempotent)."""
        if getattr(self, "_h", None):
            self._lib.gb_close(self._h)
            self._h = None

    def __enter__(self) -> Mega2560:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()

    def reset(self) -> None:
        """Pull the reset pin: the firmware restarts from its reset vector."""
        self._lib.gb_reset(self._handle)

    # ---- time ----------------------------------------------------------------------------------

    @property
    def cycle(self) -> int:
        """Emulated CPU cycles since power-on (16 per microsecond)."""
        return int(self._lib.gb_cycle(self._handle))

    @property
    def time_us(self) -> float:
        """Emulated time since power-on (us)."""
        return self.cycle / CYCLES_PER_US

    def run_until(self, cycle: int) -> None:
        """Run the CPU until ``cycle``.

        Raises
        ------
        RuntimeError
            If the CPU crashed or stopped (the harness's last log line says why).
        """
        state = self._lib.gb_run_until(self._handle, int(cycle))
        if state not in (2, 3):  # running, sleeping
            name = CPU_STATES[state] if 0 <= state < len(CPU_STATES) else str(state)
            raise RuntimeError(
                f"the emulated CPU is {name} at cycle {self.cycle}: {self.last_log or 'no log'}"
            )

    def run_us(self, us: float) -> None:
        """Run for ``us`` microseconds of emulated time."""
        self.run_until(self.cycle + round(us * CYCLES_PER_US))

    def run_ms(self, ms: float) -> None:
        """Run for ``ms`` milliseconds of emulated time."""
        self.run_until(self.cycle + round(ms * CYCLES_PER_MS))

    # ---- peripherals ---------------------------------------------------------------------------

    def set_adc(self, counts: int, channel: int = 0) -> None:
        """Put the voltage that converts to ``counts`` (0..1023) on ADC ``channel``."""
        self._lib.gb_set_adc_counts(self._handle, channel, int(counts))

    def write(self, data: bytes) -> int:
        """Queue bytes on the line to the board; they arrive one frame time apart.

        Returns the number accepted (the line holds 64 KiB).
        """
        return int(self._lib.gb_rx_write(self._handle, bytes(data), len(data)))

    @property
    def rx_pending(self) -> int:
        """Bytes queued on the line that have not reached the board yet."""
        return int(self._lib.gb_rx_pending(self._handle))

    @property
    def rx_last_cycle(self) -> int:
        """Cycle at which the last byte queued so far has completely arrived."""
        return int(self._lib.gb_rx_last_cycle(self._handle))

    def read_tx(self) -> np.ndarray:
        """Bytes the firmware transmitted since the last call (``TX_DTYPE``: cycle, byte)."""
        return self._drain(self._lib.gb_tx_read, self._tx_buf)

    def read(self) -> bytes:
        """Bytes the firmware transmitted since the last call."""
        return self.read_tx()["byte"].tobytes()

    def read_pulses(self) -> np.ndarray:
        """Servo pulses completed since the last call (``PULSE_DTYPE``, cycles)."""
        return self._drain(self._lib.gb_pulses_read, self._pulse_buf)

    def watch_pin(self, port: str, bit: int) -> int:
        """Record the edges of output pin ``port``/``bit`` (``"B", 7`` = pin 13); its index."""
        index = self._lib.gb_watch_pin(self._handle, port.encode(), bit)
        if index < 0:
            raise ValueError(f"cannot watch pin P{port}{bit}")
        return int(index)

    def read_edges(self) -> np.ndarray:
        """Edges of the watched pins since the last call (``EDGE_DTYPE``)."""
        return self._drain(self._lib.gb_edges_read, self._edge_buf)

    def _drain(self, fn: object, buf: np.ndarray) -> np.ndarray:
        parts = []
        while True:
            n = fn(self._handle, buf.ctypes.data, len(buf))  # type: ignore[operator]
            parts.append(buf[:n].copy())
            if n < len(buf):
                break
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    # ---- introspection -------------------------------------------------------------------------

    def stats(self) -> dict[str, int]:
        """Counters of the harness (cycles, instructions, sleep, UART, pulses, stack...)."""
        s = _Stats()
        self._lib.gb_stats(self._handle, ctypes.byref(s))
        return {name: getattr(s, name) for name, _ in _Stats._fields_}

    def profile(self, enable: bool = True) -> None:
        """Start (or stop) counting the cycles spent at each instruction address."""
        if self._lib.gb_profile(self._handle, int(enable)) != 0:
            raise MemoryError("cannot allocate the cycle profile")

    def read_profile(self) -> np.ndarray:
        """Cycles per flash word address since the last call (index = byte address / 2)."""
        out = np.zeros(1 << 17, np.uint32)
        n = self._lib.gb_profile_read(self._handle, out.ctypes.data, len(out))
        return out[:n]

    def reset_stack_mark(self) -> None:
        """Forget the stack low-water mark (to measure from now on)."""
        self._lib.gb_reset_sp_min(self._handle)

    @property
    def stack_peak_bytes(self) -> int:
        """Deepest stack use seen (bytes below RAMEND)."""
        s = self.stats()
        return s["ramend"] - s["sp_min"]

    @property
    def last_log(self) -> str:
        """The last warning or error simavr logged."""
        return (self._lib.gb_last_log(self._handle) or b"").decode(errors="replace").strip()


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

    def receive(self, data: bytes, now_us: int | None = None) -> None:
        """Bytes from the host: onto the RX line now, one frame time apart."""
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


# ---- command line ------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m gripper_env.hardware.emulator``: the real firmware on a pty.

    The same options as ``python -m gripper_env.hardware.virtual`` (it prints the pty path to
    pass as ``--port``), plus ``--image`` and ``--rebuild``; the image and the harness are built
    by the project's scripts when missing.
    """
    from gripper_env.hardware import virtual

    args = list(sys.argv[1:] if argv is None else argv)
    return virtual.main(args, emulated=True)


if __name__ == "__main__":
    sys.exit(main())

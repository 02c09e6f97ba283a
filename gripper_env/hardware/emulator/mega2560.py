"""One emulated ATmega2560 running a firmware image: :class:`Mega2560`.

It loads ``firmware/build-mega/gripper.elf`` into simavr at 16 MHz through the harness
``firmware/emulator/board.c`` (a small C library over Debian's ``libsimavr``, loaded with
:mod:`ctypes`): bytes on UART0 (paced at the line rate), the voltage on A0 in ADC counts, the
servo pulses Timer1 drives on pin 11, edges of the firmware's timing pins (13: control path,
12: telemetry frame), the stack's low-water mark, and a cycle profile.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import numpy as np

from gripper_env.hardware.emulator.build import (
    DEFAULT_HARNESS,
    DEFAULT_IMAGE,
    EmulatorUnavailable,
)

__all__ = [
    "CPU_HZ",
    "CYCLES_PER_MS",
    "CYCLES_PER_US",
    "EDGE_DTYPE",
    "EMULATED_DEVICE_ID",
    "PULSE_DTYPE",
    "TX_DTYPE",
    "Mega2560",
]

CPU_HZ = 16_000_000  # the Mega 2560's crystal
CYCLES_PER_US = CPU_HZ // 1_000_000
CYCLES_PER_MS = CPU_HZ // 1000
ABI_VERSION = 1  # GB_ABI_VERSION in board.h
EMULATED_DEVICE_ID = 0x454D554C  # "EMUL" in EEPROM bytes 0-3

PULSE_DTYPE = np.dtype(
    [("start", "<u8"), ("width", "<u4"), ("ocr", "<u2"), ("top", "<u2")], align=True
)
EDGE_DTYPE = np.dtype([("cycle", "<u8"), ("pin", "u1"), ("level", "u1")], align=True)
TX_DTYPE = np.dtype([("cycle", "<u8"), ("byte", "u1")], align=True)

# simavr's cpu states (sim_avr.h)
CPU_STATES = ("limbo", "stopped", "running", "sleeping", "step", "step_done", "done", "crashed")


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
        return {name: getattr(s, name) for name, *_ in _Stats._fields_}

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

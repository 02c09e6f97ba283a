"""Two-point ADC-to-angle calibration of the jaw potentiometer, and its file.

The Mega reads the potentiometer with a 10-bit ADC; the jaw angle is the straight line through
two points measured with the jaw at 21 deg (closed) and 92 deg (open):

``angle_deg = 21 + (adc - adc_at_21) * (92 - 21) / (adc_at_92 - adc_at_21)``

``python -m tuners.rig.calibrate --port P`` measures the points and writes them to a small JSON
file;
the device (CONFIGURE's ``adc_at_lo``/``adc_at_hi``) and the host (counts -> deg) both use it.

Calibrations are per board: one file per board in :func:`calibrations_dir`
(``~/.config/gripper_env/calibrations/``, or ``$GRIPPER_CALIBRATION_DIR``), named by the board's
identity (:func:`device_key`: its EEPROM device id, as INFO reports it; a board whose id was
never written, 0xFFFFFFFF, by its port as well). A virtual board (id "VIRT") or the emulated one
("EMUL") thus never replaces a real board's calibration. ``record`` and ``deploy`` take the
board's own file after the handshake, and refuse a file given to them (``--calibration``, or
``$GRIPPER_CALIBRATION``) whose device is not the board's (:func:`check_device`). A file of
the earlier single location (:data:`DEFAULT_PATH`) is still read for the board it names.

File format (JSON):

.. code-block:: json

    {"format": "gripper-calibration", "format_version": 1,
     "adc_at_21_deg": 80.2, "adc_at_92_deg": 348.6,
     "date": "2025-01-01T12:00:00+00:00", "port": "/dev/ttyACM0",
     "device_id": 4294967295, "samples": 500, "noise_counts": [0.4, 0.5]}

The counts are averages (fractional); the device gets them rounded to whole counts.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from gripper_env.hardware.safety import (
    ADC_MAX_COUNT,
    CAL_ANGLE_HI_DEG,
    CAL_ANGLE_LO_DEG,
)
from gripper_env.io.files import read_format_json, write_json

__all__ = [
    "CALIBRATIONS_DIR",
    "DEFAULT_PATH",
    "UNSET_DEVICE_ID",
    "Calibration",
    "CalibrationError",
    "board_calibration",
    "calibration_path_for",
    "calibrations_dir",
    "check_device",
    "default_calibration_path",
    "device_key",
    "device_text",
    "load_calibration",
    "save_calibration",
]

FORMAT = "gripper-calibration"
FORMAT_VERSION = 1
#: The single calibration file of earlier versions (still read for the board it names).
DEFAULT_PATH = Path("~/.config/gripper_env/calibration.json")
#: Where each board's calibration lives (one file per board, :func:`device_key`).
CALIBRATIONS_DIR = Path("~/.config/gripper_env/calibrations")
#: The device id of a board whose EEPROM id was never written (bytes 0-3 erased).
UNSET_DEVICE_ID = 0xFFFFFFFF
#: Names of the project's own boards' ids (gripper_env.hardware.twin.rig, .emulator.mega2560).
_KNOWN_IDS = {0x56495254: "the virtual board", 0x454D554C: "the emulated board",
              UNSET_DEVICE_ID: "id never written"}  # fmt: skip
_MIN_SPAN_COUNTS = 20  # the firmware refuses calibration points closer than this


class CalibrationError(ValueError):
    """A calibration file is missing or malformed, or the points are unusable."""


def default_calibration_path() -> Path:
    """``$GRIPPER_CALIBRATION`` if set, else ``~/.config/gripper_env/calibration.json``."""
    env = os.environ.get("GRIPPER_CALIBRATION")
    return Path(env).expanduser() if env else DEFAULT_PATH.expanduser()


def calibrations_dir() -> Path:
    """``$GRIPPER_CALIBRATION_DIR`` if set, else :data:`CALIBRATIONS_DIR`."""
    env = os.environ.get("GRIPPER_CALIBRATION_DIR")
    return Path(env).expanduser() if env else CALIBRATIONS_DIR.expanduser()


def device_key(device_id: int | None, port: str) -> str:
    """The name of a board's calibration file: its device id in hex (``56495254``); for a
    board whose id was never written (or is unknown), ``unset-id-`` and its port
    (``unset-id-dev-ttyACM0``), the only other thing that tells two such boards apart."""
    if device_id is not None and int(device_id) != UNSET_DEVICE_ID:
        return f"{int(device_id):08x}"
    name = re.sub(r"[^A-Za-z0-9._-]+", "-", str(port)).strip("-.") or "port"
    return f"unset-id-{name[:80]}"


def calibration_path_for(device_id: int | None, port: str) -> Path:
    """Where the calibration of the board ``device_id`` on ``port`` lives."""
    return calibrations_dir() / f"{device_key(device_id, port)}.json"


def device_text(device_id: object, port: object = None) -> str:
    """``device 0x56495254 (the virtual board) on /dev/pts/3`` for the messages."""
    if device_id is None:
        text = "an unknown device"
    else:
        try:
            n = int(device_id)  # type: ignore[call-overload]
            text = f"device 0x{n:08X}" + (f" ({_KNOWN_IDS[n]})" if n in _KNOWN_IDS else "")
        except (TypeError, ValueError):
            text = f"device {device_id!r}"
    return text + (f" on {port}" if port else "")


def check_device(cal: Calibration, device_id: int | None, port: str, source: object) -> None:
    """Refuse the calibration ``cal`` (read from ``source``) for the board ``device_id`` on
    ``port`` when it was measured on another board (its ``device_id`` differs), naming both.
    A file without a device id (written by hand) is taken as it is.

    Raises
    ------
    CalibrationError
    """
    theirs = cal.extra.get("device_id")
    if theirs is None or device_id is None:
        return
    try:
        same = int(theirs) == int(device_id)
    except (TypeError, ValueError):
        same = False
    if not same:
        raise CalibrationError(
            f"{source}: the calibration of {device_text(theirs, cal.port or None)}, not of this "
            f"board, {device_text(device_id, port)}; calibrate this board: python -m "
            f"tuners.rig.calibrate --port {port}"
        )


def board_calibration(
    device_id: int | None,
    port: str,
    given: Calibration | None = None,
    source: object = "--calibration",
) -> Calibration:
    """The calibration for the board ``device_id`` on ``port`` (after the handshake).

    ``given`` (read from ``source``, ``--calibration`` or ``$GRIPPER_CALIBRATION``) is checked
    against the board (:func:`check_device`); without it, the board's own file
    (:func:`calibration_path_for`), else the single file of earlier versions if it names this
    board.

    Raises
    ------
    CalibrationError
        The given calibration is another board's, or this board has none (naming where it was
        looked for and the command that makes one).
    """
    if given is not None:
        check_device(given, device_id, port, source)
        return given
    own = calibration_path_for(device_id, port)
    if own.exists():
        cal = load_calibration(own)
        check_device(cal, device_id, port, own)
        return cal
    legacy = DEFAULT_PATH.expanduser()
    if legacy.is_file():
        cal = load_calibration(legacy)
        theirs = cal.extra.get("device_id")
        if theirs is not None and device_id is not None and int(theirs) == int(device_id):
            return cal
    raise CalibrationError(
        f"no calibration for {device_text(device_id, port)} at {own}: run 'python -m "
        f"tuners.rig.calibrate --port {port}' first"
    )


@dataclass(frozen=True)
class Calibration:
    """ADC counts at the two calibration angles (21 and 92 deg).

    Parameters
    ----------
    adc_at_21_deg, adc_at_92_deg : float
        Mean ADC counts (0..1023) with the jaw at 21 deg and at 92 deg.
    date : str
        When it was measured (ISO 8601, UTC).
    port : str
        Serial port of the device it was measured on.
    extra : dict
        Anything else worth keeping (device id, sample counts, noise).
    """

    adc_at_21_deg: float
    adc_at_92_deg: float
    date: str = ""
    port: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("adc_at_21_deg", "adc_at_92_deg"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise CalibrationError(f"calibration {name} must be a finite number, got {value!r}")
            if not 4 <= value <= ADC_MAX_COUNT - 4:
                raise CalibrationError(
                    f"calibration {name}={value:g} counts is at the ADC rail (0..1023): "
                    "is the potentiometer connected?"
                )
        if abs(self.adc_at_92_deg - self.adc_at_21_deg) < _MIN_SPAN_COUNTS:
            raise CalibrationError(
                f"calibration points {self.adc_at_21_deg:g} and {self.adc_at_92_deg:g} counts are "
                f"less than {_MIN_SPAN_COUNTS} counts apart: the jaw did not move"
            )

    @property
    def device_counts(self) -> tuple[int, int]:
        """The two points rounded to whole counts, as CONFIGURE sends them."""
        return round(self.adc_at_21_deg), round(self.adc_at_92_deg)

    @property
    def deg_per_count(self) -> float:
        """Slope of the line (deg per count; negative if the counts fall as the jaw opens)."""
        return (CAL_ANGLE_HI_DEG - CAL_ANGLE_LO_DEG) / (self.adc_at_92_deg - self.adc_at_21_deg)

    def to_deg(self, adc: np.ndarray | float, as_device: bool = True) -> np.ndarray:
        """Jaw angle (deg) from ADC counts.

        Parameters
        ----------
        adc : array-like
            ADC counts.
        as_device : bool
            Use the whole-count points the device uses (default), so host and board agree.
        """
        lo, hi = self.device_counts if as_device else (self.adc_at_21_deg, self.adc_at_92_deg)
        slope = (CAL_ANGLE_HI_DEG - CAL_ANGLE_LO_DEG) / (hi - lo)
        return CAL_ANGLE_LO_DEG + (np.asarray(adc, dtype=float) - lo) * slope

    def to_dict(self) -> dict[str, Any]:
        """The file's content."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "adc_at_21_deg": float(self.adc_at_21_deg),
            "adc_at_92_deg": float(self.adc_at_92_deg),
            "date": self.date,
            "port": self.port,
            **self.extra,
        }

    @classmethod
    def measured(
        cls, adc_at_21_deg: float, adc_at_92_deg: float, port: str = "", **extra: Any
    ) -> Calibration:
        """A calibration measured now (the date is set to the current UTC time)."""
        date = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        return cls(float(adc_at_21_deg), float(adc_at_92_deg), date, port, dict(extra))


def save_calibration(cal: Calibration, path: str | os.PathLike[str] | None = None) -> Path:
    """Write ``cal`` as JSON, atomically (:func:`gripper_env.io.files.write_json`); return the
    path."""
    p = Path(path).expanduser() if path is not None else default_calibration_path()
    return write_json(p, cal.to_dict())


def load_calibration(
    path: str | os.PathLike[str] | None = None, option: str | None = None
) -> Calibration:
    """Read a calibration file (default :func:`default_calibration_path`; ``option``, the
    command-line option that named it, for the refusals).

    Raises
    ------
    CalibrationError
        The file is missing, not JSON, not a calibration file, or holds unusable points.
    """
    p = Path(path).expanduser() if path is not None else default_calibration_path()
    if not p.exists():
        raise CalibrationError(
            f"no calibration file at {p}: run 'python -m tuners.rig.calibrate --port PORT' first"
        )
    content = read_format_json(p, FORMAT, "calibration file", CalibrationError, option)
    if content.get("format_version") != FORMAT_VERSION:
        raise CalibrationError(
            f"{p}: calibration format version {content.get('format_version')!r} is not "
            f"supported (this version reads {FORMAT_VERSION})"
        )
    known = {"format", "format_version", "adc_at_21_deg", "adc_at_92_deg", "date", "port"}
    try:
        return Calibration(
            cast(float, content.get("adc_at_21_deg")),  # Calibration checks them
            cast(float, content.get("adc_at_92_deg")),
            str(content.get("date", "")),
            str(content.get("port", "")),
            {k: v for k, v in content.items() if k not in known},
        )
    except CalibrationError as exc:
        raise CalibrationError(f"{p}: {exc}") from None

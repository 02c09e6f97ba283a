"""Telemetry on the host: :class:`TelemetryBlock` (samples as arrays) and
:class:`TelemetryClock`, which turns TELEMETRY messages into blocks on an unwrapped device clock.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.protocol import SampleFlag

__all__ = ["TelemetryBlock", "TelemetryClock"]


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
    def concatenate(cls, blocks: Sequence[TelemetryBlock]) -> TelemetryBlock:
        blocks = [b for b in blocks if len(b)]
        if not blocks:
            return cls.empty()
        if len(blocks) == 1:
            return blocks[0]
        return cls(*(np.concatenate([getattr(b, f) for b in blocks]) for f in _BLOCK_FIELDS))

    def select(self, index: np.ndarray | slice) -> TelemetryBlock:
        """The samples at ``index`` (a boolean mask or a slice) as a block."""
        return TelemetryBlock(*(getattr(self, f)[index] for f in _BLOCK_FIELDS))

    @classmethod
    def empty(cls) -> TelemetryBlock:
        f, i = np.zeros(0), np.zeros(0, dtype=np.int64)
        return cls(i, f, f.copy(), i.copy(), f.copy(), np.zeros(0, dtype=np.uint8))


_BLOCK_FIELDS = ("t_us", "reference_deg", "command_deg", "adc", "position_deg", "flags")
_SAMPLE_DTYPE = np.dtype([("r", "<i2"), ("u", "<i2"), ("adc", "<u2"), ("flags", "u1")])


class TelemetryClock:
    """Turns TELEMETRY messages into :class:`TelemetryBlock` s with one monotonic device time.

    The board stamps each batch with ``micros()`` (u32, wraps every 71.6 min); the clock unwraps
    it and counts the samples that never arrived (gaps between consecutive batches).

    Attributes
    ----------
    latest_us : int or None
        Device time (us, unwrapped) of the newest sample.
    samples_missing : int
        Samples missing between the batches seen so far.
    """

    def __init__(self) -> None:
        self.latest_us: int | None = None
        self.samples_missing = 0
        self._last_raw: int | None = None
        self._offset = 0
        self._next_us: int | None = None

    def block(self, msg: proto.Telemetry, calibration: Calibration | None = None) -> TelemetryBlock:
        """The samples of ``msg``; ``position_deg`` through ``calibration`` (NaN without one)."""
        raw = msg.t0_us
        if self._last_raw is not None and raw < self._last_raw and self._last_raw - raw > (1 << 31):
            self._offset += 1 << 32  # micros() wrapped
        self._last_raw = raw
        step = msg.decimation * 1000
        n = len(msg.samples)
        t = self._offset + raw + step * np.arange(n, dtype=np.int64)
        if self._next_us is not None and t[0] > self._next_us:
            self.samples_missing += int((t[0] - self._next_us) // max(step, 1))
        self._next_us = int(t[-1]) + step
        self.latest_us = int(t[-1])
        arr = np.array(
            [(s.reference_cdeg, s.command_cdeg, s.adc, s.flags) for s in msg.samples],
            dtype=_SAMPLE_DTYPE,
        )
        ref = np.where(arr["r"] == proto.CDEG_NONE, np.nan, arr["r"] / 100.0)
        cmd = np.where(arr["u"] == proto.CDEG_NONE, np.nan, arr["u"] / 100.0)
        adc = arr["adc"].astype(np.int64)
        pos = calibration.to_deg(adc) if calibration else np.full(n, np.nan)
        return TelemetryBlock(t, ref, cmd, adc, pos, arr["flags"].copy())

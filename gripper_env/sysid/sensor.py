"""The sensor read from a record alone: ADC resolution and offset, and the measurement noise.

The potentiometer goes through a 10-bit ADC, so the logged angle lies on a grid
``adc_lo + k * lsb`` (:class:`gripper_env.model.disturbances.Sensor`). From the logged values:

- **resolution** ``lsb``: the spacing of the grid, the typical gap between neighbouring distinct
  values (they are all visited when the noise is about a count or more);
- **offset** ``adc_lo`` (the angle read as count 0), known only modulo one count from the data:
  the grid's phase, the circular mean of ``y / lsb``; the representative nearest a prior
  (the preset's) is reported;
- **noise** (Gaussian, before quantisation): from the second differences of the record,
  ``var(y[k] - 2 y[k-1] + y[k-2]) = 6 (sigma^2 + lsb^2 / 12)`` for white noise (the ADC adds its
  own ``lsb^2 / 12``, Sheppard), which the jaw's motion hardly touches: a held or slowly moving
  jaw has zero second difference, and the few samples of a fast step or a slip are cut off by
  an iterative 4-sigma clip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SensorEstimate", "estimate_sensor"]

# A value grid counts as seen when the logged values take few distinct levels.
_MAX_LEVEL_FRACTION = 0.2


@dataclass(frozen=True)
class SensorEstimate:
    """What the record says about the sensor.

    Attributes
    ----------
    noise_std_deg : float
        Standard deviation of the Gaussian measurement noise before quantisation (deg).
    lsb_deg : float
        ADC resolution (deg per count); 0 when the values are not quantised.
    adc_lo_deg : float
        Angle read as count 0 (deg), the grid's phase placed nearest the prior.
    quantised : bool
        Whether the values lie on a grid.
    clipped_fraction : float
        Share of second differences cut off as motion, not noise.
    """

    noise_std_deg: float
    lsb_deg: float
    adc_lo_deg: float
    quantised: bool
    clipped_fraction: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "noise_std_deg": self.noise_std_deg,
            "lsb_deg": self.lsb_deg,
            "adc_lo_deg": self.adc_lo_deg,
            "quantised": self.quantised,
            "clipped_fraction": self.clipped_fraction,
        }


def _grid(y: np.ndarray, resolution: float) -> tuple[float, float] | None:
    """``(lsb, phase)`` of the grid the values lie on, or None if they do not."""
    levels = np.unique(np.round(y / resolution) * resolution)
    if levels.size < 3 or levels.size > _MAX_LEVEL_FRACTION * y.size:
        return None
    gaps = np.diff(levels)
    smallest = float(np.min(gaps))
    near = gaps[gaps < 1.5 * smallest]
    if near.size < 0.5 * gaps.size:
        return None
    lsb = float(np.median(near))
    # the levels as multiples of lsb: refine lsb by least squares through their counts
    k = np.round((levels - levels[0]) / lsb)
    if np.max(np.abs((levels - levels[0]) / lsb - k)) > 0.2:
        return None
    lsb = float(np.polyfit(k, levels, 1)[0]) if np.ptp(k) > 0 else lsb
    angle = 2 * np.pi * y / lsb
    phase = float(np.arctan2(np.mean(np.sin(angle)), np.mean(np.cos(angle))))
    return lsb, (phase / (2 * np.pi)) * lsb


def estimate_sensor(
    y: np.ndarray, *, prior_adc_lo_deg: float = 0.0, resolution_deg: float = 1e-6
) -> SensorEstimate:
    """Estimate the ADC grid and the measurement noise from a record's measured output.

    Parameters
    ----------
    y : ndarray
        Measured angle (deg), one value per sample, uniformly sampled.
    prior_adc_lo_deg : float
        Where the angle of count 0 is expected (deg); the grid's phase is reported as the
        representative nearest it.
    resolution_deg : float
        Resolution of the logged numbers (deg; the logs carry 6 decimals).
    """
    y = np.asarray(y, dtype=float)
    grid = _grid(y, resolution_deg)
    lsb, lo = (0.0, prior_adc_lo_deg) if grid is None else grid
    if grid is not None:
        lo = lo + lsb * round((prior_adc_lo_deg - lo) / lsb)
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    keep = np.ones(d2.size, dtype=bool)
    sd = float(np.std(d2))
    for _ in range(20):
        new = np.abs(d2) <= 4.0 * sd
        sd_new = float(np.std(d2[new])) if new.any() else 0.0
        if np.array_equal(new, keep) or sd_new == 0.0:
            keep = new
            break
        keep, sd = new, sd_new
    var_q = float(np.mean(d2[keep] ** 2)) / 6.0 if keep.any() else 0.0
    # a 4-sigma clip of a Gaussian keeps 99.994 % of it and 99.87 % of its variance
    var_q /= 0.99887
    noise = math.sqrt(max(var_q - lsb**2 / 12.0, 0.0))
    return SensorEstimate(
        noise_std_deg=noise,
        lsb_deg=lsb,
        adc_lo_deg=float(lo),
        quantised=grid is not None,
        clipped_fraction=float(1.0 - keep.mean()) if keep.size else 0.0,
    )

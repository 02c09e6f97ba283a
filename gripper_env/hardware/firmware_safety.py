"""What keeps the jaw safe whatever the host sends, in Python: the twin of the firmware's
``gripper_safety.h``.

The jaw clamp, the potentiometer's two-point calibration and its rails, the servo pulse's hard
limits and the host watchdog's timeout, with the same constants as the C++ unit.
"""

from __future__ import annotations

import math

__all__ = [
    "ADC_MAX_COUNT",
    "ADC_MIN_CAL_SPAN",
    "ADC_RAIL_MARGIN",
    "CAL_ANGLE_HI_DEG",
    "CAL_ANGLE_LO_DEG",
    "JAW_CLOSED_DEG",
    "JAW_OPEN_DEG",
    "SENSOR_FAULT_TICKS",
    "SERVO_MIN_CAL_SPAN_US",
    "SERVO_PULSE_MAX_US",
    "SERVO_PULSE_MIN_US",
    "WATCHDOG_TIMEOUT_US",
    "adc_at_rail",
    "adc_to_deg",
    "clamp_jaw",
    "deg_to_adc",
    "finite",
]

WATCHDOG_TIMEOUT_US = 500_000  # host silence that triggers the safe stop (us)
JAW_CLOSED_DEG = 21.0
JAW_OPEN_DEG = 92.0
CAL_ANGLE_LO_DEG = 21.0  # the two calibration points (deg)
CAL_ANGLE_HI_DEG = 92.0
ADC_MAX_COUNT = 1023
ADC_RAIL_MARGIN = 4
ADC_MIN_CAL_SPAN = 20
SENSOR_FAULT_TICKS = 20
SERVO_PULSE_MIN_US = 400
SERVO_PULSE_MAX_US = 2600
SERVO_MIN_CAL_SPAN_US = 500


def clamp_jaw(x: float, lo: float, hi: float, safe: float) -> float:
    """Clamp a servo command (deg) into ``[lo, hi]``; NaN goes to ``safe`` (C++ ``clamp_jaw``)."""
    if x != x:
        return safe
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


def adc_to_deg(adc: float, adc_at_lo: float, adc_at_hi: float) -> float:
    """Jaw angle (deg) from ADC counts by the two-point line through 21 and 92 deg."""
    slope = (CAL_ANGLE_HI_DEG - CAL_ANGLE_LO_DEG) / (adc_at_hi - adc_at_lo)
    return CAL_ANGLE_LO_DEG + (adc - adc_at_lo) * slope


def deg_to_adc(deg: float, adc_at_lo: float, adc_at_hi: float) -> int:
    """ADC counts (rounded, saturated to 0..1023) that the calibration maps to ``deg``."""
    if deg != deg:
        return 0
    counts = adc_at_lo + (deg - CAL_ANGLE_LO_DEG) * (adc_at_hi - adc_at_lo) / (
        CAL_ANGLE_HI_DEG - CAL_ANGLE_LO_DEG
    )
    if not counts > 0:
        return 0
    if counts >= ADC_MAX_COUNT:
        return ADC_MAX_COUNT
    return int(counts + 0.5)


def adc_at_rail(adc: int) -> bool:
    """A reading this close to 0 or 1023 counts means a broken wire."""
    return adc < ADC_RAIL_MARGIN or adc > ADC_MAX_COUNT - ADC_RAIL_MARGIN


def finite(x: float) -> bool:
    """Neither NaN nor infinite (C++ ``is_finite``)."""
    return math.isfinite(x)

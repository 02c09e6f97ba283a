"""What keeps the jaw safe whatever the host sends, in Python: the twin of the firmware's
``gripper_safety.h``.

The jaw clamp, the potentiometer's two-point calibration and its rails, the hard limits compiled
into the image (the jaw range 21-92 deg and the servo pulses it maps to, 760.5-1492.5 us, with the
build's default servo mapping 544/2400 us), the servo pulse and the host watchdog's timeout,
with the same constants as the C++ unit.
"""

from __future__ import annotations

import math

__all__ = [
    "ADC_MAX_COUNT",
    "ADC_MIN_CAL_SPAN",
    "ADC_RAIL_MARGIN",
    "CAL_ANGLE_HI_DEG",
    "CAL_ANGLE_LO_DEG",
    "HARD_PULSE_TICKS",
    "JAW_CLOSED_DEG",
    "JAW_HARD_MAX_DEG",
    "JAW_HARD_MIN_DEG",
    "JAW_OPEN_DEG",
    "SENSOR_FAULT_TICKS",
    "SERVO_MIN_CAL_SPAN_US",
    "SERVO_PULSE_MAX_US",
    "SERVO_PULSE_MIN_US",
    "SERVO_US_DEFAULT",
    "WATCHDOG_TIMEOUT_US",
    "adc_at_rail",
    "adc_to_deg",
    "clamp_jaw",
    "deg_to_adc",
    "finite",
    "servo_pulse_ticks",
    "servo_pulse_ticks_raw",
]

WATCHDOG_TIMEOUT_US = 500_000  # host silence that triggers the safe stop (us)
JAW_CLOSED_DEG = 21.0
JAW_OPEN_DEG = 92.0
JAW_HARD_MIN_DEG = 21.0  # the hard jaw range of the default build (GRIPPER_JAW_HARD_MIN/MAX_DEG)
JAW_HARD_MAX_DEG = 92.0
SERVO_US_DEFAULT = (544, 2400)  # the build's servo mapping (GRIPPER_SERVO_US_AT_0/180)
CAL_ANGLE_LO_DEG = 21.0  # the two calibration points (deg)
CAL_ANGLE_HI_DEG = 92.0
ADC_MAX_COUNT = 1023
ADC_RAIL_MARGIN = 4
ADC_MIN_CAL_SPAN = 20
SENSOR_FAULT_TICKS = 20
SERVO_PULSE_MIN_US = 400
SERVO_PULSE_MAX_US = 2600
SERVO_MIN_CAL_SPAN_US = 500


def servo_pulse_ticks_raw(deg: float, us_at_0: int, us_at_180: int) -> int:
    """Servo pulse (Timer1 ticks of 0.5 us) a mapping gives ``deg``, before any limit: ``(2
    us_at_0 + 1/2) + deg * ticks_per_deg``, truncated (C++ ``servo_pulse_ticks_raw``)."""
    ticks_per_deg = 2.0 * (us_at_180 - us_at_0) / 180.0
    return int((2 * us_at_0 + 0.5) + deg * ticks_per_deg)


def _hard_pulse_ticks() -> tuple[int, int]:
    a = servo_pulse_ticks_raw(JAW_HARD_MIN_DEG, *SERVO_US_DEFAULT)
    b = servo_pulse_ticks_raw(JAW_HARD_MAX_DEG, *SERVO_US_DEFAULT)
    return min(a, b), max(a, b)


HARD_PULSE_TICKS = _hard_pulse_ticks()  # (1521, 2985): 760.5-1492.5 us, every pulse lies in it


def servo_pulse_ticks(deg: float, us_at_0: int, us_at_180: int) -> int:
    """The servo pulse (ticks of 0.5 us) for an angle (deg): clamped to the servo range, rounded
    and clamped into :data:`HARD_PULSE_TICKS` whatever the mapping (C++ ``servo_pulse_ticks``)."""
    deg = clamp_jaw(deg, 0.0, 180.0, JAW_OPEN_DEG)
    lo, hi = HARD_PULSE_TICKS
    return min(max(servo_pulse_ticks_raw(deg, us_at_0, us_at_180), lo), hi)


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

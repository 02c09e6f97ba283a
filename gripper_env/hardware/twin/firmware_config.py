"""What CONFIGURE sets, validated like the firmware does: the twin of ``DeviceConfig`` and
``validate_configure`` in ``gripper_device.h``."""

from __future__ import annotations

import math

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.safety import (
    ADC_MIN_CAL_SPAN,
    HARD_PULSE_TICKS,
    JAW_CLOSED_DEG,
    JAW_HARD_MAX_DEG,
    JAW_HARD_MIN_DEG,
    JAW_OPEN_DEG,
    SERVO_MIN_CAL_SPAN_US,
    SERVO_PULSE_MAX_US,
    SERVO_PULSE_MIN_US,
    adc_at_rail,
    servo_pulse_ticks_raw,
)
from gripper_env.hardware.safety import finite as _finite

__all__ = ["MAX_DECIMATION", "TICK_PERIOD_US", "FirmwareConfig", "validate_configure"]

TICK_PERIOD_US = 1000  # control period (us)
MAX_DECIMATION = 1000


class FirmwareConfig:
    """Everything CONFIGURE sets, validated (the C++ ``DeviceConfig``); defaults after HELLO."""

    __slots__ = (
        "adc_at_hi",
        "adc_at_lo",
        "anti_windup",
        "batch",
        "d",
        "d_on_meas",
        "decimation",
        "dwell",
        "grasp",
        "i",
        "jaw_max",
        "jaw_min",
        "kb",
        "n",
        "p",
        "push",
        "servo_us_at_0",
        "servo_us_at_180",
        "shortfall",
        "sign",
        "squeeze",
        "still",
        "u_max",
        "u_min",
    )

    def __init__(self) -> None:
        self.p = self.i = self.d = 0.0
        self.n = 100.0
        self.u_min, self.u_max = JAW_CLOSED_DEG, JAW_OPEN_DEG
        self.anti_windup = proto.AntiWindup.CLAMPING
        self.kb = 1.0
        self.sign = 1.0
        self.d_on_meas = 0
        # the grasp mode, on: a gripper's controller holds an object without stalling its servo
        self.grasp = 1
        self.squeeze, self.push, self.shortfall, self.still = 1.0, 5.0, 0.5, 1.0
        self.dwell = 100
        self.jaw_min, self.jaw_max = JAW_CLOSED_DEG, JAW_OPEN_DEG
        self.adc_at_lo, self.adc_at_hi = 119, 523
        self.servo_us_at_0, self.servo_us_at_180 = 544, 2400
        self.decimation = 1
        self.batch = 10


def _pulses_inside(m: proto.Configure) -> bool:
    """The mapping gives both ends of the jaw range pulses inside the hard window."""
    lo, hi = HARD_PULSE_TICKS
    return all(
        lo <= servo_pulse_ticks_raw(deg, m.servo_us_at_0, m.servo_us_at_180) <= hi
        for deg in (m.jaw_min, m.jaw_max)
    )


def validate_configure(m: proto.Configure) -> tuple[FirmwareConfig | None, int]:
    """Check a CONFIGURE like the firmware: ``(config, 0)`` or ``(None, first bad field index)``.

    Besides each field's own rule, the jaw range must lie inside the hard range compiled into the
    image and the servo mapping must give it pulses inside the hard window (field 11,
    ``servo_us_at_0``, names the mapping).
    """
    n_dt = np.float32(m.n) * np.float32(TICK_PERIOD_US * 1e-6)  # float32, as on the board
    checks = (
        _finite(m.p),
        _finite(m.i),
        _finite(m.d),
        _finite(m.n) and m.n > 0.0 and float(n_dt) < 2.0,
        m.u_min == m.u_min and m.u_min != math.inf,
        m.u_max == m.u_max and m.u_max != -math.inf and m.u_min < m.u_max,
        _finite(m.kb),
        _finite(m.jaw_min) and JAW_HARD_MIN_DEG <= m.jaw_min <= JAW_HARD_MAX_DEG,
        _finite(m.jaw_max)
        and JAW_HARD_MIN_DEG <= m.jaw_max <= JAW_HARD_MAX_DEG
        and m.jaw_min < m.jaw_max,
    )
    for index, ok in enumerate(checks):
        if not ok:
            return None, index
    if not m.u_min < m.jaw_max:
        return None, 4
    if not m.u_max > m.jaw_min:
        return None, 5
    rest = (
        not adc_at_rail(m.adc_at_lo),
        not adc_at_rail(m.adc_at_hi) and abs(m.adc_at_lo - m.adc_at_hi) >= ADC_MIN_CAL_SPAN,
        SERVO_PULSE_MIN_US <= m.servo_us_at_0 <= SERVO_PULSE_MAX_US,
        SERVO_PULSE_MIN_US <= m.servo_us_at_180 <= SERVO_PULSE_MAX_US
        and abs(m.servo_us_at_0 - m.servo_us_at_180) >= SERVO_MIN_CAL_SPAN_US,
        m.decimation <= MAX_DECIMATION,
        m.anti_windup <= proto.AntiWindup.BACK_CALCULATION,
        m.sign in (1, -1),
        m.d_on_meas <= 1,
        1 <= m.telemetry_batch <= proto.TELEMETRY_MAX_SAMPLES,
    )
    for index, ok in enumerate(rest, start=9):
        if not ok:
            return None, index
        if index == 12 and not _pulses_inside(m):
            return None, 11
    if m.grasp > 1:
        return None, 18
    if m.grasp:  # the grasp mode's settings, checked only when it is on
        grasp = (
            _finite(m.grasp_squeeze_deg) and m.grasp_squeeze_deg > 0.0,
            _finite(m.grasp_push_deg) and m.grasp_push_deg > m.grasp_squeeze_deg,
            _finite(m.grasp_short_deg) and m.grasp_short_deg > 0.0,
            _finite(m.grasp_still_deg) and m.grasp_still_deg > 0.0,
            m.grasp_dwell_ticks >= 1,
        )
        for index, ok in enumerate(grasp, start=19):
            if not ok:
                return None, index
    c = FirmwareConfig()
    c.p, c.i, c.d, c.n = m.p, m.i, m.d, m.n
    c.u_min = max(m.u_min, m.jaw_min)
    c.u_max = min(m.u_max, m.jaw_max)
    c.anti_windup = m.anti_windup
    c.kb = m.kb
    c.sign = float(m.sign)
    c.d_on_meas = 1 if m.d_on_meas else 0
    c.grasp = 1 if m.grasp else 0
    if c.grasp:  # else the defaults, rather than unchecked values
        c.squeeze, c.push = m.grasp_squeeze_deg, m.grasp_push_deg
        c.shortfall, c.still = m.grasp_short_deg, m.grasp_still_deg
        c.dwell = m.grasp_dwell_ticks
    c.jaw_min, c.jaw_max = m.jaw_min, m.jaw_max
    c.adc_at_lo, c.adc_at_hi = m.adc_at_lo, m.adc_at_hi
    c.servo_us_at_0, c.servo_us_at_180 = m.servo_us_at_0, m.servo_us_at_180
    c.decimation = m.decimation
    c.batch = m.telemetry_batch
    return c, 0

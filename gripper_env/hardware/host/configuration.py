"""The CONFIGURE message the host sends for a controller: PID gains and options, the jaw's
calibration, and the link settings (:meth:`GripperDevice.configure
<gripper_env.hardware.host.device.GripperDevice.configure>` and the scripted host send it)."""

from __future__ import annotations

from typing import Any

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.model.pid import ANTI_WINDUP_MODES, PIDGains, PIDOptions

#: The board's control period (us): the grasp mode's dwell goes in its ticks.
TICK_PERIOD_US = 1000

__all__ = ["configure_message"]


def configure_message(
    gains: PIDGains, options: PIDOptions, calibration: Calibration, **fields: Any
) -> proto.Configure:
    """The CONFIGURE for these gains, options and calibration; ``fields`` set the others.

    The grasp mode (``options.grasp``) goes with it: on, with its settings and its dwell in the
    board's 1 ms ticks; off, ``grasp = 0`` (its settings then the defaults, unchecked).
    """
    lo, hi = calibration.device_counts
    on, squeeze, push, short, still, dwell = options.grasp_row(TICK_PERIOD_US * 1e-6)
    values: dict[str, Any] = {
        "p": float(gains.P),
        "i": float(gains.I),
        "d": float(gains.D),
        "n": float(gains.N),
        "u_min": float(options.output_limits[0]),
        "u_max": float(options.output_limits[1]),
        "kb": float(options.kb),
        "adc_at_lo": lo,
        "adc_at_hi": hi,
        "anti_windup": ANTI_WINDUP_MODES[options.anti_windup],
        "sign": int(options.sign),
        "d_on_meas": 1 if options.derivative_on == "measurement" else 0,
        "grasp": on,
        "grasp_squeeze_deg": squeeze,
        "grasp_push_deg": push,
        "grasp_short_deg": short,
        "grasp_still_deg": still,
        "grasp_dwell_ticks": int(dwell),
    }
    values.update(fields)
    return proto.Configure(**values)

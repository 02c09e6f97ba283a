"""The CONFIGURE message the host sends for a controller: PID gains and options, the jaw's
calibration, and the link settings (:meth:`GripperDevice.configure
<gripper_env.hardware.host.device.GripperDevice.configure>` and the scripted host send it)."""

from __future__ import annotations

from typing import Any

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.model.pid import ANTI_WINDUP_MODES, PIDGains, PIDOptions

__all__ = ["configure_message"]


def configure_message(
    gains: PIDGains, options: PIDOptions, calibration: Calibration, **fields: Any
) -> proto.Configure:
    """The CONFIGURE for these gains, options and calibration; ``fields`` set the others."""
    lo, hi = calibration.device_counts
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
    }
    values.update(fields)
    return proto.Configure(**values)

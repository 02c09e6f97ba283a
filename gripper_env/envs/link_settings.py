"""The link arguments of the hardware environment (``GripperServoHardware-v0``), checked.

The port, and the timing and telemetry settings of the serial link; a bad one fails at
construction with a message that names the environment and the argument (as
:func:`gripper_env.envs.settings.parse_settings` does for the episode settings).
"""

from __future__ import annotations

import math
import os
from typing import Any

from gripper_env.io.config import ConfigError

__all__ = ["check_link_arguments", "check_port"]


def check_port(name: str, port: Any, render_mode: Any) -> str:
    """``port`` as a path; refuse a missing or malformed one and any ``render_mode``, naming the
    argument."""
    if port is None or (isinstance(port, str) and not port):
        raise ConfigError(
            f"{name}: argument 'port' is required: the board's serial port (e.g. "
            "port='/dev/ttyACM0'), a pyserial URL, or the path a virtual board prints "
            "(python -m tuners.rig.virtual)"
        )
    if not isinstance(port, str | os.PathLike):
        raise ConfigError(f"{name}: argument 'port': expected a path or URL, got {port!r}")
    if render_mode is not None:
        raise ConfigError(
            f"{name}: argument 'render_mode': no rendering on hardware (a plot would cost "
            f"the real-time loop its deadlines), got {render_mode!r}"
        )
    return os.fspath(port)


def check_link_arguments(
    name: str,
    boot_wait_s: Any,
    timeout_s: Any,
    settle_tol_deg: Any,
    settle_timeout_s: Any,
    telemetry_batch: Any,
    warn_every: Any,
) -> None:
    """Refuse a bad timing or telemetry argument with a message that names it."""
    for arg, value, low in (
        ("boot_wait_s", boot_wait_s, 0.0),
        ("timeout_s", timeout_s, 1e-3),
        ("settle_tol_deg", settle_tol_deg, 1e-3),
        ("settle_timeout_s", settle_timeout_s, 0.0),
    ):
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= low):
            raise ConfigError(f"{name}: argument {arg!r}: expected a number >= {low:g}, "
                              f"got {value!r}")  # fmt: skip
    for arg, value, high in (
        ("telemetry_batch", telemetry_batch, 32),
        ("warn_every", warn_every, None),
    ):
        if not (isinstance(value, int) and value >= 1 and (high is None or value <= high)):
            bounds = f"1..{high}" if high else ">= 1"
            raise ConfigError(f"{name}: argument {arg!r}: expected an integer {bounds}, "
                              f"got {value!r}")  # fmt: skip

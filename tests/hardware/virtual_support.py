"""Helpers for the tests that talk to a virtual board over a pseudo-terminal."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from gripper_env.hardware.calibration import Calibration
from gripper_env.hardware.device import GripperDevice
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.references import step_profile

REPO = Path(__file__).resolve().parents[2]
SPEED = 5.0  # device time runs 5x faster than wall time: a 7 s profile takes 1.4 s


def true_calibration(vd: VirtualDevice) -> Calibration:
    """The calibration a perfect measurement of the virtual rig finds."""
    lo, hi = vd.rig.true_calibration
    return Calibration(lo, hi, port=vd.path)


def open_device(vd: VirtualDevice, **kwargs: object) -> GripperDevice:
    kwargs.setdefault("calibration", true_calibration(vd))
    kwargs.setdefault("timeout_s", 0.5)
    return GripperDevice(vd.path, boot_wait_s=0.0, **kwargs)  # type: ignore[arg-type]


def short_step():
    """Grip at 0.5 s, un-grip at 3.5 s, end at 6.5 s (deg, 1 ms)."""
    return step_profile(hold_s=0.5, grip_s=3.0, ungrip_s=3.0)


def run_cli(module: str, *args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """Run ``python -m module args`` from the repository, bounded by ``timeout_s``."""
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )

"""Helpers for the tests that talk to a virtual board over a pseudo-terminal."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.model.references import step_profile

REPO = Path(__file__).resolve().parents[2]
#: Device time runs at wall time, as on the board: its watchdog stops it after 500 ms without a
#: host frame, which at 5x was 100 ms of wall time, and a test's host thread went that long
#: without running at load 12 on 2 cores (a run ended in a WATCHDOG stop). A 7 s profile takes
#: 7 s, most of it waiting.
SPEED = 1.0


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


def gains_file(path: Path, p: float, i: float, d: float) -> str:
    """A gains file for test2 (clamping, the jaw range as output limits); returns its path."""
    content = {
        "format": "gripper-gains",
        "format_version": 1,
        "plant": "test2",
        "tuner": "manual",
        "P": p,
        "I": i,
        "D": d,
        "N": 100.0,
        "sign": 1,
        "limits": {"output_deg": [21.0, 92.0], "anti_windup": "clamping", "kb": 1.0},
    }
    path.write_text(json.dumps(content))
    return str(path)


def short_step_csv(
    path: Path, grip_s: float = 0.5, ungrip_s: float = 2.5, end_s: float = 4.0
) -> str:
    """A step profile as a CSV (t_s, reference_deg, 10 ms apart): 92 deg, 21 from ``grip_s`` to
    ``ungrip_s``, 92 again until ``end_s``; returns its path."""
    t = np.arange(0, end_s, 0.01)
    r = np.where((t >= grip_s) & (t < ungrip_s), 21.0, 92.0)
    np.savetxt(path, np.column_stack([t, r]), delimiter=",", header="t_s,reference_deg",
               comments="")  # fmt: skip
    return str(path)

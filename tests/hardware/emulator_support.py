"""Helpers for the tests that run the compiled firmware under simavr (the emulated board)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.board import EmulatedBoard
from gripper_env.hardware.emulator.mega2560 import CYCLES_PER_MS
from gripper_env.hardware.emulator.scripted import ScriptedHost
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.twin.rig import VirtualRig
from gripper_env.hardware.virtual import VirtualDevice

SERVO_US = (544.0, 2400.0)
FRAME_CYCLES = 20 * CYCLES_PER_MS  # Timer1's 50 Hz period


def pulse_cycles(deg: float) -> int:
    """Width (cycles at 16 MHz) of the firmware's pulse for ``deg`` with the default servo
    calibration: 0.5 us timer ticks, rounded to the nearest (independent of the firmware's code)."""
    ticks = round(2 * (SERVO_US[0] + deg * (SERVO_US[1] - SERVO_US[0]) / 180.0))
    return ticks * 8


def new_board(build: tuple[Path, Path], disturbance: object = "actual", seed: int = 0):
    image, harness = build
    rig = VirtualRig("test2", disturbance, seed, 92.0, pulse_train=True)
    return EmulatedBoard(rig, image=image, harness=harness, record=True)


def calibration_of(board: EmulatedBoard) -> Calibration:
    return Calibration(*board.rig.true_calibration)


def session(board: EmulatedBoard, **configure: object) -> ScriptedHost:
    """Boot 50 ms, HELLO and CONFIGURE (the rig's true calibration, the fields given)."""
    host = ScriptedHost(board)
    host.run(50)
    lo, hi = calibration_of(board).device_counts
    host.open_session(proto.Configure(**{"adc_at_lo": lo, "adc_at_hi": hi, **configure}))
    return host


def emulated_device(build: tuple[Path, Path], **kwargs: object) -> VirtualDevice:
    """The image behind a pty (the harness from this session's build)."""
    image, harness = build
    kwargs.setdefault("seed", 3)
    return VirtualDevice("test2", "actual", image=image, harness=harness, **kwargs)  # type: ignore[arg-type]


def ends(pulses: np.ndarray) -> np.ndarray:
    return pulses["start"].astype(np.int64) + pulses["width"].astype(np.int64)

"""Shared pieces of the environment tests."""

import numpy as np

SERVO = "gripper_env/GripperServo-v0"
PID_TUNE = "gripper_env/GripperPIDTune-v0"
GAIN_SCHEDULE = "gripper_env/GripperGainSchedule-v0"
ENV_IDS = (SERVO, PID_TUNE, GAIN_SCHEDULE)

# Everything random at once: plants drawn, actual-gripper parameters drawn, random references.
RANDOMIZED = {
    "plant": ["test1", "test2", "test3", "test4"],
    "randomize": True,
    "reference": "random",
    "episode_s": 1.0,
}


def signed_log_gains(action, gain_max=(10.0, 50.0, 0.1)):
    """The documented action -> gain map, written out independently of the library."""
    a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    return np.sign(a) * np.asarray(gain_max) * (10.0 ** (3.0 * np.abs(a)) - 1.0) / 999.0

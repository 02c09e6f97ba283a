"""Hand-written policies as plain callables, ``obs (B, n_obs) -> actions (B, 1)``: what a user
writes before any learning, and what ``python -m tuners.rl evaluate module:callable`` scores.

* :func:`command_reference`: the servo commanded the observed reference (the trivial policy of
  ``GripperServo-v0`` and its tasks in servo mode);
* :func:`squeeze_past_contact`: a grasp without knowing where the object is (``GripperGrasp-v0``,
  servo mode): close at full speed, and when the jaw stops short of the command it has met the
  object; then command a fixed ``SQUEEZE_DEG`` past where it stopped (40 % of stall on the
  5-deg stall band: enough force, below the thermal limit), and hold.

Both read only the observation (``GripperServo-v0``'s layout: position, reference, error, error
rate, error integral, previous action, normalised by the jaw's and the command's ranges).
"""

from __future__ import annotations

import numpy as np

__all__ = ["SQUEEZE_DEG", "command_reference", "squeeze_past_contact"]

#: The hobby-servo gripper's jaw range (deg) and command range (deg): the observation's and the
#: action's normalisation (``GripperServo-v0``'s defaults, the paper's 21-92 deg and 0-180 deg).
_JAW = (21.0, 92.0)
_COMMAND = (0.0, 180.0)
#: How far past the stopped jaw the grasp commands the servo (deg).
SQUEEZE_DEG = 2.0
#: A jaw that moved less than this in a 20 ms period has stopped (deg): above the sensor's noise
#: on one period's difference (0.3 deg sd per sample, two samples) and far below a closing
#: jaw's 2-20 deg per period.
_STOPPED_DEG = 1.0


def _unpack(obs: np.ndarray) -> tuple[np.ndarray, ...]:
    o = np.atleast_2d(np.asarray(obs, dtype=np.float64))
    jc, jh = 0.5 * (_JAW[0] + _JAW[1]), 0.5 * (_JAW[1] - _JAW[0])
    cc, ch = 0.5 * (_COMMAND[0] + _COMMAND[1]), 0.5 * (_COMMAND[1] - _COMMAND[0])
    y, r = jc + jh * o[:, 0], jc + jh * o[:, 1]
    moved = np.abs(o[:, 3]) * jh  # the error's change over the last period (deg)
    previous = cc + ch * o[:, 5]
    return y, r, moved, previous


def _action(command_deg: np.ndarray) -> np.ndarray:
    cc, ch = 0.5 * (_COMMAND[0] + _COMMAND[1]), 0.5 * (_COMMAND[1] - _COMMAND[0])
    return np.clip((command_deg - cc) / ch, -1.0, 1.0).astype(np.float32)[:, None]


def command_reference(obs: np.ndarray) -> np.ndarray:
    """The servo commanded the observed reference."""
    _, r, _, _ = _unpack(obs)
    return _action(r)


def squeeze_past_contact(obs: np.ndarray) -> np.ndarray:
    """Close at full speed; where the jaw stops short of the command, squeeze
    :data:`SQUEEZE_DEG` past it and hold (module docstring)."""
    y, r, moved, previous = _unpack(obs)
    closing = r < y - 1.0  # the reference asks the jaw to close further
    stopped = moved < _STOPPED_DEG
    pushing = previous < y - SQUEEZE_DEG - 1.0  # the last command lay well past the jaw
    squeezing = np.abs(previous - (y - SQUEEZE_DEG)) <= 1.5  # already holding
    command = np.where(closing & stopped & (pushing | squeezing), y - SQUEEZE_DEG, r)
    return _action(command)

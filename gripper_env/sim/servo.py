"""The servo's command path: range clamp, quantisation, rate limit and the 50 Hz command hold.

A hobby servo reads a new position command only on its refresh ticks (every 20 ms at 50 Hz);
Arduino's ``Servo.write`` sends whole degrees, ``writeMicroseconds`` about 0.1 deg. On a tick the
controller's output ``u`` (deg) is clamped to the servo's range, rounded to the command quantum,
rate-limited against the previous command, and latched; between ticks the servo holds it. The
configuration is :class:`gripper_env.model.disturbances.CommandPath`.

Parameters (a tuple, :func:`servo_params`): ``(cmd_lo, cmd_hi, quantum, refresh, step_max)`` -
range (deg), quantum (deg, 0 for none), refresh period (physics steps), largest change per tick
(deg, 0 for no rate limit).

State (a tuple, :func:`load_servo`): ``(cmd, countdown, cmd_clip, servo_tv)`` - held command
(deg), physics steps to the next tick, 1.0 while the held command is clipped to the range, and
the total variation of the held command so far (deg: the servo's effort counter).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from gripper_env.model.disturbances import CommandPath
from gripper_env.sim.layout import (
    P_CMD_HI,
    P_CMD_LO,
    P_QUANTUM,
    P_RATE,
    P_REFRESH,
    S_CMD,
    S_CMDCLIP,
    S_COUNTDOWN,
    S_SERVO_TV,
)
from gripper_env.sim.rounding import round_half_up

__all__ = ["load_servo", "servo_columns", "servo_params", "servo_step", "store_servo"]

ServoParams = tuple[float, float, float, float, float]
ServoState = tuple[float, float, float, float]


def servo_columns(c: CommandPath, dt_s: float) -> dict[int, float]:
    """Parameter columns of the command path ``c`` at the physics step ``dt_s`` (s)."""
    return {
        P_CMD_LO: c.range_deg[0],
        P_CMD_HI: c.range_deg[1],
        P_QUANTUM: c.quantum_deg,
        P_REFRESH: max(1, round(c.refresh_period_s / dt_s)),
        P_RATE: c.rate_limit_deg_s,
    }


@njit(inline="always")
def servo_params(params: np.ndarray, b: int, dt: float) -> ServoParams:
    """Run ``b``'s command-path parameters (see the module docstring); ``dt`` in s."""
    refresh = params[b, P_REFRESH]
    step_max = params[b, P_RATE] * refresh * dt
    return params[b, P_CMD_LO], params[b, P_CMD_HI], params[b, P_QUANTUM], refresh, step_max


@njit(inline="always")
def load_servo(state: np.ndarray, b: int) -> ServoState:
    """Run ``b``'s command-path state."""
    return state[b, S_CMD], state[b, S_COUNTDOWN], state[b, S_CMDCLIP], state[b, S_SERVO_TV]


@njit(inline="always")
def store_servo(state: np.ndarray, b: int, s: ServoState) -> None:
    """Write run ``b``'s command-path state back."""
    state[b, S_CMD], state[b, S_COUNTDOWN], state[b, S_CMDCLIP], state[b, S_SERVO_TV] = s


@njit(inline="always")
def servo_step(u: float, s: ServoState, p: ServoParams) -> ServoState:
    """One physics step of the command path.

    Parameters
    ----------
    u : float
        Controller output at this step (deg).
    s : tuple of 4 float
        ``(cmd, countdown, cmd_clip, servo_tv)`` before the step.
    p : tuple of 5 float
        ``(cmd_lo, cmd_hi, quantum, refresh, step_max)``.

    Returns
    -------
    tuple of 4 float
        The state after the step; its ``cmd`` is the command the servo acts on (deg).
    """
    cmd, countdown, cmd_clip, servo_tv = s
    cmd_lo, cmd_hi, quantum, refresh, step_max = p
    if countdown <= 0.0:  # a refresh tick: latch a new command
        c = u
        cmd_clip = 0.0
        if c > cmd_hi:
            c = cmd_hi
            cmd_clip = 1.0
        elif c < cmd_lo:
            c = cmd_lo
            cmd_clip = 1.0
        if quantum > 0.0:
            c = quantum * round_half_up(c / quantum)
        if step_max > 0.0:
            if c > cmd + step_max:
                c = cmd + step_max
            elif c < cmd - step_max:
                c = cmd - step_max
        servo_tv += abs(c - cmd)
        cmd = c
        countdown = refresh
    countdown -= 1.0
    return cmd, countdown, cmd_clip, servo_tv

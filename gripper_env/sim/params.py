"""The core's parameter matrix: one row per run, from gains, PID options and the gripper blocks.

Each block module maps its configuration to its columns (:func:`~gripper_env.sim.servo.
servo_columns`, :func:`~gripper_env.sim.friction.friction_columns`, :func:`~gripper_env.sim.
mechanics.mechanics_columns`, :func:`~gripper_env.sim.sensor.sensor_columns`); the layout is
:mod:`gripper_env.sim.layout`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import ANTI_WINDUP_MODES, DERIVATIVE_ON, PIDGains, PIDOptions
from gripper_env.sim.friction import friction_columns
from gripper_env.sim.layout import (
    N_PARAMS,
    P_AW,
    P_CMD_LO,
    P_DMEAS,
    P_DWELL,
    P_GRASP,
    P_KB,
    P_N,
    P_P,
    P_SIGN,
    P_UHI,
    P_ULO,
)
from gripper_env.sim.mechanics import mechanics_columns
from gripper_env.sim.sensor import sensor_columns
from gripper_env.sim.servo import servo_columns

__all__ = ["as_gain_rows", "build_params", "disturbance_row"]


def as_gain_rows(gains: Any) -> np.ndarray:
    """Gains as a (B, 4) float array ``[P, I, D, N]`` (N defaults to 100 1/s).

    Parameters
    ----------
    gains : array-like (B, 3|4) or (3|4,), PIDGains, or list of PIDGains
        ``[P (deg/deg), I (1/s), D (s)(, N (1/s))]`` per run.

    Returns
    -------
    ndarray, shape (B, 4)
    """
    if isinstance(gains, PIDGains):
        return gains.as_array()[None, :]
    if isinstance(gains, Sequence) and gains and isinstance(gains[0], PIDGains):
        return np.stack([g.as_array() for g in gains])
    arr = np.asarray(gains, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] not in (3, 4):
        raise ValueError(
            f"gains must be (P, I, D[, N]) or an array of shape (B, 3) or (B, 4), got shape "
            f"{arr.shape}"
        )
    if arr.shape[1] == 3:
        arr = np.concatenate([arr, np.full((arr.shape[0], 1), 100.0)], axis=1)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"gains must be finite numbers; gain set {i} is {arr[i].tolist()}")
    if np.any(arr[:, 3] <= 0):
        raise ValueError("the derivative filter coefficient N must be positive")
    return arr


def build_params(
    gains: np.ndarray | None,
    disturbances: Sequence[Disturbance],
    dt_s: float,
    pid_options: PIDOptions | None = None,
    n_runs: int | None = None,
) -> np.ndarray:
    """Parameter matrix (B, N_PARAMS) of the kernel from gains and actual-gripper blocks.

    Parameters
    ----------
    gains : ndarray, shape (B, 4), or None
        ``[P, I, D, N]`` per run; ``None`` for open loop (the PID columns stay zero).
    disturbances : sequence of Disturbance
        One per run, or one shared by all.
    dt_s : float
        Physics step (s).
    pid_options : PIDOptions, optional
        Output limits, anti-windup, derivative input, sign convention and grasp mode.
    n_runs : int, optional
        Batch size, when one gain set and one disturbance are shared by more runs.

    Returns
    -------
    ndarray, shape (B, N_PARAMS)
    """
    opts = pid_options or PIDOptions()
    n = max(len(disturbances), 0 if gains is None else gains.shape[0], n_runs or 0)
    params = np.zeros((n, N_PARAMS))
    if gains is not None:
        params[:, P_P : P_N + 1] = gains
        if np.any(gains[:, 3] * dt_s >= 2.0):
            raise ValueError(
                f"derivative filter coefficient N must satisfy N*dt < 2 (dt = {dt_s} s) for a "
                "stable Forward Euler filter"
            )
    params[:, P_ULO], params[:, P_UHI] = opts.output_limits
    params[:, P_KB] = opts.kb
    params[:, P_SIGN] = opts.sign
    params[:, P_AW] = ANTI_WINDUP_MODES[opts.anti_windup]
    params[:, P_DMEAS] = DERIVATIVE_ON[opts.derivative_on]
    params[:, P_GRASP : P_DWELL + 1] = opts.grasp_row(dt_s)
    rows = [disturbance_row(d, dt_s) for d in disturbances]
    params[:, P_CMD_LO:] = rows[0] if len(rows) == 1 else np.stack(rows)
    return params


def disturbance_row(d: Disturbance, dt_s: float) -> np.ndarray:
    """The gripper blocks' part of a parameter row (columns from ``P_CMD_LO``) at step ``dt_s``."""
    row = np.zeros(N_PARAMS - P_CMD_LO)
    values = {
        **servo_columns(d.command, dt_s),
        **friction_columns(d.friction),
        **mechanics_columns(d.mechanics),
        **sensor_columns(d.sensor, dt_s),
    }
    for key, value in values.items():
        row[key - P_CMD_LO] = value
    return row

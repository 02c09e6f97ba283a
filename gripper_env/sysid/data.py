"""Checking and preparing input/output records for identification.

Every estimator in :mod:`gripper_env.sysid` calls :func:`prepare_data` first, so all of them refuse
the same bad inputs with the same messages and remove the operating point the same way.

Operating point (``offset``), removed before fitting and restored by the estimates' ``simulate``
(:func:`gripper_env.sysid.tfest` then refines ``y_op`` jointly with the model by default):

- ``"initial"`` (default): ``u_op = u[0]``; ``y_op`` = mean of ``y`` over the leading samples during
  which ``u`` still equals ``u[0]`` (the rest period before the first move; just ``y[0]`` if the
  input moves at once). The identified model maps deviations from the initial rest point, which is
  how the gripper experiments start (at rest at 92 deg).
- ``"mean"``: ``u_op = mean(u)``, ``y_op = mean(y)``, like MATLAB's ``detrend(data, 0)``.
- ``"none"``: ``u_op = y_op = 0``; the raw data are fitted and the estimated initial state must
  carry the operating point (MATLAB on raw data with ``InitialCondition = 'estimate'``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "OFFSET_MODES",
    "IOData",
    "NonUniformSamplingWarning",
    "as_signal",
    "prepare_data",
]

OFFSET_MODES = ("initial", "mean", "none")
Offset = Literal["initial", "mean", "none"]

# Relative spread of the sample intervals treated as float rounding of a uniform grid.
_UNIFORM_RTOL = 1e-6


class NonUniformSamplingWarning(UserWarning):
    """The time stamps were mildly non-uniform and the data were resampled."""


@dataclass(frozen=True)
class IOData:
    """A uniformly sampled record with its operating point removed.

    Attributes
    ----------
    dt_s : float
        Sample interval (s).
    t0_s : float
        Time of the first sample (s); 0 when only ``dt_s`` was given.
    u, y : ndarray
        Input and output deviations from the operating point (deg).
    u_op, y_op : float
        Operating point (deg): the absolute signals are ``u + u_op`` and ``y + y_op``.
    offset : str
        How the operating point was chosen (see the module docstring).
    resampled : bool
        True if the time stamps were mildly non-uniform and the data were resampled.
    """

    dt_s: float
    t0_s: float
    u: np.ndarray
    y: np.ndarray
    u_op: float
    y_op: float
    offset: str
    resampled: bool = False

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.u.size)

    @property
    def y_abs(self) -> np.ndarray:
        """Measured output in absolute units (deg)."""
        return self.y + self.y_op


def as_signal(x: ArrayLike, name: str) -> np.ndarray:
    """Convert ``x`` to a finite 1-D float array or raise a ``ValueError`` naming ``name``."""
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if arr.ndim == 0:
        raise ValueError(f"{name} must be a 1-D array of samples, got a scalar")
    arr = np.squeeze(arr) if arr.ndim > 1 and sum(s > 1 for s in arr.shape) <= 1 else arr
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"{name} is empty")
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{name} contains a non-finite value ({arr[i]}) at index {i}")
    return arr


def _uniform_grid(
    t: np.ndarray, u: np.ndarray, y: np.ndarray, max_jitter: float
) -> tuple[float, float, np.ndarray, np.ndarray, bool]:
    dts = np.diff(t)
    if np.any(dts <= 0):
        i = int(np.argmax(dts <= 0))
        raise ValueError(
            f"time stamps must be strictly increasing (t_s[{i + 1}] = {t[i + 1]} <= "
            f"t_s[{i}] = {t[i]})"
        )
    dt = float(np.median(dts))
    spread = float(np.max(np.abs(dts - dt)) / dt)
    if spread <= _UNIFORM_RTOL:
        return float((t[-1] - t[0]) / (t.size - 1)), float(t[0]), u, y, False
    if spread > max_jitter:
        i = int(np.argmax(np.abs(dts - dt)))
        raise ValueError(
            f"non-uniform time stamps: interval {dts[i]:.6g} s at index {i} differs from the "
            f"median {dt:.6g} s by {100 * spread:.3g} % (more than max_jitter = "
            f"{100 * max_jitter:.3g} %); resample the data or raise max_jitter"
        )
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    grid = t[0] + dt * np.arange(n)
    # The input is a held command: take the last value at or before each grid instant.
    idx = np.clip(np.searchsorted(t, grid + 1e-9 * dt, side="right") - 1, 0, t.size - 1)
    u_new = u[idx]
    y_new = np.interp(grid, t, y)
    warnings.warn(
        f"mildly non-uniform time stamps (max deviation {100 * spread:.3g} % of the median "
        f"interval {dt:.6g} s): resampled to a uniform grid (input held, output interpolated)",
        NonUniformSamplingWarning,
        stacklevel=4,
    )
    return dt, float(t[0]), u_new, y_new, True


def prepare_data(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    min_samples: int = 1,
    offset: Offset = "initial",
    max_jitter: float = 0.05,
    model: str = "",
) -> IOData:
    """Validate a record, put it on a uniform grid and remove the operating point.

    Parameters
    ----------
    time_s : float or array_like
        Either the sample interval ``dt_s`` (s, a scalar) or the time stamps ``t_s`` (s, one per
        sample).
    u, y : array_like
        Input (desired angle, deg) and output (actual angle, deg), one value per sample.
    min_samples : int
        Fewest samples the caller's model needs.
    offset : {"initial", "mean", "none"}
        Operating point to remove (see the module docstring).
    max_jitter : float
        Largest relative deviation of a sample interval from the median interval that is
        repaired by resampling (with a :class:`NonUniformSamplingWarning`); beyond it the data are
        refused. Deviations below 1e-6 count as float rounding and are accepted silently.
    model : str
        Description of the model order for the "too short" message.

    Returns
    -------
    IOData

    Raises
    ------
    ValueError
        Empty, non-numeric or non-finite data; lengths that differ; too few samples for the
        model; a constant input or output; non-increasing or too non-uniform time stamps; a bad
        ``dt_s`` or ``offset``.
    """
    if offset not in OFFSET_MODES:
        raise ValueError(f"offset must be one of {OFFSET_MODES}, got {offset!r}")
    u_arr = as_signal(u, "u")
    y_arr = as_signal(y, "y")
    if u_arr.size != y_arr.size:
        raise ValueError(f"u and y have different lengths ({u_arr.size} and {y_arr.size} samples)")
    if np.ndim(time_s) == 0:
        try:
            dt = float(time_s)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise ValueError(f"dt_s must be a number, got {time_s!r}") from None
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt_s must be a positive finite sample interval (s), got {dt}")
        t0 = 0.0
        resampled = False
    else:
        t_arr = as_signal(time_s, "t_s")
        if t_arr.size != u_arr.size:
            raise ValueError(
                f"t_s and u have different lengths ({t_arr.size} and {u_arr.size} samples)"
            )
        if t_arr.size < 2:
            raise ValueError("t_s needs at least two time stamps to define the sample interval")
        dt, t0, u_arr, y_arr, resampled = _uniform_grid(t_arr, u_arr, y_arr, max_jitter)
    if u_arr.size < min_samples:
        what = f" for {model}" if model else ""
        raise ValueError(
            f"data too short for the model order: {u_arr.size} samples, need at least "
            f"{min_samples}{what}"
        )
    if np.ptp(u_arr) == 0:
        raise ValueError(
            f"u is constant ({u_arr[0]} for all samples): it does not excite the system"
        )
    if np.ptp(y_arr) == 0:
        raise ValueError(f"y is constant ({y_arr[0]} for all samples): there is no response to fit")
    if offset == "initial":
        moved = np.flatnonzero(u_arr != u_arr[0])
        k = int(moved[0]) if moved.size else u_arr.size
        u_op = float(u_arr[0])
        y_op = float(np.mean(y_arr[: max(k, 1)]))
    elif offset == "mean":
        u_op = float(np.mean(u_arr))
        y_op = float(np.mean(y_arr))
    else:
        u_op = y_op = 0.0
    return IOData(
        dt_s=dt,
        t0_s=t0,
        u=u_arr - u_op,
        y=y_arr - y_op,
        u_op=u_op,
        y_op=y_op,
        offset=offset,
        resampled=resampled,
    )

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
    "DEFAULT_MAX_GAP",
    "DEFAULT_MAX_JITTER",
    "OFFSET_MODES",
    "TIME_BASES",
    "IOData",
    "NonUniformSamplingWarning",
    "as_signal",
    "fit_grid",
    "held_average",
    "prepare_data",
]

OFFSET_MODES = ("initial", "mean", "none")
Offset = Literal["initial", "mean", "none"]

#: Default tolerance of :func:`prepare_data`: time stamps within this fraction of a sample interval
#: of a uniform grid are taken as that grid (snapped).
DEFAULT_MAX_JITTER = 0.3
#: Default refusal threshold: a sample interval this many times the median one is a gap.
DEFAULT_MAX_GAP = 4.0
# Deviations below this fraction of an interval are float rounding: "uniform", not "snapped".
_ROUNDING = 1e-6

TIME_BASES = ("uniform", "snapped", "resampled", "interval")


class NonUniformSamplingWarning(UserWarning):
    """The time stamps were too irregular to be a grid and the data were resampled."""


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
    time_base : str
        ``"interval"`` (only ``dt_s`` was given), ``"uniform"`` (stamps on a grid to float
        rounding), ``"snapped"`` (stamps within ``max_jitter`` of a grid, taken as the grid) or
        ``"resampled"`` (irregular stamps, resampled).
    jitter : float
        Largest deviation of a time stamp from the fitted uniform grid, as a fraction of ``dt_s``
        (0 when only ``dt_s`` was given).
    jitter_std : float
        Standard deviation of the time stamps about that grid, as a fraction of ``dt_s``, when
        they were snapped to it (0 otherwise): the spread of the instants the samples were
        taken at about the instants the fit assumes, which the error model of the standard
        errors includes (:mod:`gripper_env.sysid.error_model`).
    r : ndarray or None
        Reference of a closed loop (deviation from ``r_op``, deg), when one was given.
    r_op : float
        Operating point of the reference (deg).
    """

    dt_s: float
    t0_s: float
    u: np.ndarray
    y: np.ndarray
    u_op: float
    y_op: float
    offset: str
    time_base: str = "interval"
    jitter: float = 0.0
    jitter_std: float = 0.0
    r: np.ndarray | None = None
    r_op: float = 0.0

    @property
    def stamp_std_s(self) -> float:
        """Spread of the sampling instants about the grid (s): ``jitter_std * dt_s``."""
        return self.jitter_std * self.dt_s

    @property
    def resampled(self) -> bool:
        """True if irregular time stamps were resampled onto a uniform grid."""
        return self.time_base == "resampled"

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.u.size)

    @property
    def y_abs(self) -> np.ndarray:
        """Measured output in absolute units (deg)."""
        return self.y + self.y_op

    @property
    def t_s(self) -> np.ndarray:
        """Time of each sample on the uniform grid (s)."""
        return self.t0_s + self.dt_s * np.arange(self.n_samples)


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


def fit_grid(t: np.ndarray) -> tuple[float, float, float]:
    """Least-squares uniform grid through time stamps: ``t_k ~ t0 + k dt``.

    Returns
    -------
    dt_s, t0_s : float
        Interval and start of the grid (s).
    jitter : float
        Largest ``|t_k - (t0 + k dt)|`` as a fraction of ``dt``.
    """
    dt, t0, dev = _grid_deviations(t)
    return dt, t0, float(np.max(np.abs(dev)) / dt) if dt > 0 else np.inf


def _grid_deviations(t: np.ndarray) -> tuple[float, float, np.ndarray]:
    """``(dt, t0, t - (t0 + k dt))`` of the least-squares uniform grid through ``t`` (s)."""
    k = np.arange(t.size, dtype=float)
    kc = k - k.mean()
    tc = t - t[0]
    dt = float(kc @ (tc - tc.mean()) / (kc @ kc))
    t0 = float(t[0] + tc.mean() - dt * k.mean())
    return dt, t0, t - (t0 + dt * k)


def held_average(t: np.ndarray, u: np.ndarray, grid: np.ndarray, dt_s: float) -> np.ndarray:
    """Average over ``[g, g + dt)`` of the input held from each stamp to the next.

    The zero-order-hold model of the resampled record then sees the same area of input as the
    system did, with no shift: a uniform record comes back unchanged.
    """
    # integral of the held input from t[0]: piecewise linear with knots at the stamps
    area = np.concatenate([[0.0], np.cumsum(u[:-1] * np.diff(t))])
    last = t[-1] + dt_s
    t_ext = np.append(t, last)
    area_ext = np.append(area, area[-1] + u[-1] * dt_s)
    lo = np.interp(grid, t_ext, area_ext)
    hi = np.interp(np.minimum(grid + dt_s, last), t_ext, area_ext)
    return (hi - lo) / dt_s


def _time_base(
    t: np.ndarray,
    signals: list[np.ndarray],
    max_jitter: float,
    max_gap: float,
) -> tuple[float, float, list[np.ndarray], str, float, float]:
    """Put stamped samples on a uniform grid: snap, or resample (see :func:`prepare_data`);
    returns ``(dt, t0, signals, time_base, jitter, jitter_std)``."""
    dts = np.diff(t)
    if np.any(dts <= 0):
        i = int(np.argmax(dts <= 0))
        raise ValueError(
            f"time stamps must be strictly increasing (t_s[{i + 1}] = {t[i + 1]} <= "
            f"t_s[{i}] = {t[i]})"
        )
    dt, t0, dev = _grid_deviations(t)
    jitter = float(np.max(np.abs(dev)) / dt) if dt > 0 else np.inf
    if jitter <= max_jitter:
        base = "uniform" if jitter <= _ROUNDING else "snapped"
        spread = 0.0 if base == "uniform" else float(np.std(dev) / dt)
        return dt, t0, signals, base, jitter, spread
    dt = float(np.median(dts))
    gap = dts > max_gap * dt * (1.0 + 1e-6)  # float rounding of the stamps is no gap
    if gap.any():
        i = int(np.argmax(dts))
        raise ValueError(
            f"gap in the time stamps: {dts[i]:.6g} s between t_s[{i}] = {t[i]:.6g} and "
            f"t_s[{i + 1}] = {t[i + 1]:.6g}, {dts[i] / dt:.3g} times the median interval "
            f"{dt:.6g} s (samples lost?); split the record there, or allow --max-gap "
            f"{np.ceil(dts[i] / dt - 1e-6):g} (max_gap) to resample across it"
        )
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    grid = t[0] + dt * np.arange(n)
    u, y, *rest = signals
    out = [held_average(t, u, grid, dt), np.interp(grid, t, y)]
    out += [held_average(t, r, grid, dt) for r in rest]
    warnings.warn(
        f"irregular time stamps (up to {jitter:.3g} of an interval from a uniform grid, more "
        f"than --max-jitter {max_jitter:g}): resampled to a uniform grid of {dt:.6g} s (input "
        "held without a shift, output interpolated)",
        NonUniformSamplingWarning,
        stacklevel=4,
    )
    return dt, float(t[0]), out, "resampled", jitter, 0.0


def prepare_data(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    min_samples: int = 1,
    offset: Offset = "initial",
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
    model: str = "",
    r: ArrayLike | None = None,
) -> IOData:
    """Validate a record, put it on a uniform grid and remove the operating point.

    Time stamps (when ``time_s`` is an array):

    - within ``max_jitter`` of a sample interval of the least-squares uniform grid through
      them: the samples are taken as that grid (*snapped*), exactly as recorded. This covers
      float rounding of the stamps and the jitter of a logger that stamps samples taken on a
      fixed clock; resampling such data would only blur them and shift the held input.
    - otherwise (*irregular*): resampled onto a grid at the median interval, the input averaged
      over each new interval as it was held (no shift), the output interpolated, with a
      :class:`NonUniformSamplingWarning`;
    - an interval longer than ``max_gap`` median intervals (lost samples) is refused.

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
        Largest deviation of a time stamp from the uniform grid, as a fraction of the sample
        interval, that is snapped to the grid (``0 <= max_jitter < 0.5``; command line
        ``--max-jitter``).
    max_gap : float
        Longest sample interval, in median intervals, that irregular stamps may have
        (command line ``--max-gap``).
    model : str
        Description of the model order for the "too short" message.
    r : array_like, optional
        Reference of a closed loop (deg), one value per sample; checked and put on the same grid.

    Returns
    -------
    IOData

    Raises
    ------
    ValueError
        Empty, non-numeric or non-finite data; lengths that differ; too few samples for the
        model; a constant input or output; non-increasing time stamps or a gap; a bad
        ``dt_s``, ``offset``, ``max_jitter`` or ``max_gap``.
    """
    if offset not in OFFSET_MODES:
        raise ValueError(f"offset must be one of {OFFSET_MODES}, got {offset!r}")
    if not 0.0 <= max_jitter < 0.5:
        raise ValueError(
            f"max_jitter (--max-jitter) must be in [0, 0.5) of a sample interval, got {max_jitter}"
        )
    if not max_gap >= 1.0:
        raise ValueError(f"max_gap (--max-gap) must be >= 1 sample interval, got {max_gap}")
    u_arr = as_signal(u, "u")
    y_arr = as_signal(y, "y")
    if u_arr.size != y_arr.size:
        raise ValueError(f"u and y have different lengths ({u_arr.size} and {y_arr.size} samples)")
    signals = [u_arr, y_arr]
    if r is not None:
        r_arr = as_signal(r, "r")
        if r_arr.size != u_arr.size:
            raise ValueError(
                f"r and u have different lengths ({r_arr.size} and {u_arr.size} samples)"
            )
        signals.append(r_arr)
    if np.ndim(time_s) == 0:
        try:
            dt = float(time_s)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise ValueError(f"dt_s must be a number, got {time_s!r}") from None
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt_s must be a positive finite sample interval (s), got {dt}")
        t0, time_base, jitter, jitter_std = 0.0, "interval", 0.0, 0.0
    else:
        t_arr = as_signal(time_s, "t_s")
        if t_arr.size != u_arr.size:
            raise ValueError(
                f"t_s and u have different lengths ({t_arr.size} and {u_arr.size} samples)"
            )
        if t_arr.size < 2:
            raise ValueError("t_s needs at least two time stamps to define the sample interval")
        dt, t0, signals, time_base, jitter, jitter_std = _time_base(
            t_arr, signals, max_jitter, max_gap
        )
    u_arr, y_arr = signals[0], signals[1]
    r_sig = signals[2] if r is not None else None
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
    if r_sig is not None and np.ptp(r_sig) == 0:
        raise ValueError(f"r is constant ({r_sig[0]} for all samples): it excites nothing")
    r_op = 0.0
    if offset == "initial":
        moved = np.flatnonzero(u_arr != u_arr[0])
        k = int(moved[0]) if moved.size else u_arr.size
        u_op = float(u_arr[0])
        y_op = float(np.mean(y_arr[: max(k, 1)]))
        r_op = float(r_sig[0]) if r_sig is not None else 0.0
    elif offset == "mean":
        u_op = float(np.mean(u_arr))
        y_op = float(np.mean(y_arr))
        r_op = float(np.mean(r_sig)) if r_sig is not None else 0.0
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
        time_base=time_base,
        jitter=jitter,
        jitter_std=jitter_std,
        r=None if r_sig is None else r_sig - r_op,
        r_op=r_op,
    )

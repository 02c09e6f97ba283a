"""Performance metrics with MATLAB's definitions, vectorised over a batch of runs.

Definitions (DESIGN.md section 2):

* **Step metrics** (MATLAB ``stepinfo`` with ``yinit``), per grip or un-grip segment from
  ``yinit`` to ``yfinal`` with ``yn = (y - yinit) / (yfinal - yinit)``: rise time from the first
  sample with ``yn >= 0.1`` to the first with ``yn >= 0.9``; settling time = time (from the move's
  first sample) of the first sample after which ``|y - yfinal| <= 2 % |yfinal - yinit|`` for good;
  overshoot ``max(0, 100 max(yn - 1))`` %, undershoot ``max(0, -100 min(yn))`` %. Sample-based,
  without interpolation, like python-control's ``step_info``. A quantity that is never reached
  (no rise, never settles) is ``inf``, never NaN.
* **Steady-state error**: ``|mean(y) - yfinal|`` over the last 10 % of the segment (deg).
* **SD**: sample standard deviation (``ddof=1``, like MATLAB's ``std``) of the response over the
  run; **SD gap** ``|SD_reference - SD_response|``.
* **IAE, ISE, ITAE** of the tracking error ``r - y`` (deg s, deg^2 s, deg s^2), **control effort**
  = total variation of the controller output ``sum |u[k] - u[k-1]|`` (deg), **saturation time**
  (s) with the command clipped.
* **Fit %** between two responses (MATLAB ``compare``):
  ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``.

A run flagged unstable (diverged) gets ``inf`` for every error-like metric and ``stable = False``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.references import Segment

__all__ = ["Metrics", "compute_metrics", "fit_percent", "sample_sd", "step_metrics"]

STEP_KEYS = (
    "overshoot_pct",
    "undershoot_pct",
    "rise_time_s",
    "settling_time_s",
    "peak_deg",
    "steady_state_error_deg",
)
RUN_KEYS = (
    "sd_deg",
    "sd_reference_deg",
    "sd_gap_deg",
    "iae",
    "ise",
    "itae",
    "control_effort",
    "saturation_s",
)


def sample_sd(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Sample standard deviation with ``ddof=1`` (MATLAB ``std``)."""
    return np.std(x, axis=axis, ddof=1)


def fit_percent(y: np.ndarray, y_hat: np.ndarray, axis: int = -1) -> np.ndarray:
    """MATLAB ``compare`` fit (%): ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``; can be negative.

    Parameters
    ----------
    y : ndarray
        Measured (reference) response.
    y_hat : ndarray
        Response to score against it.
    """
    y = np.asarray(y, dtype=float)
    y_hat = np.asarray(y_hat, dtype=float)
    num = np.linalg.norm(y - y_hat, axis=axis)
    den = np.linalg.norm(y - np.mean(y, axis=axis, keepdims=True), axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 100.0 * (1.0 - num / den)
    return np.where(den > 0, fit, np.where(num == 0, 100.0, -np.inf))


def step_metrics(
    t_s: np.ndarray, y: np.ndarray, y_init: float, y_final: float
) -> dict[str, np.ndarray]:
    """Step metrics of a batch of responses to one move (MATLAB ``stepinfo`` with ``yinit``).

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Time from the move's first sample (s); ``t_s[0] == 0``.
    y : ndarray, shape (B, n) or (n,)
        Responses (deg).
    y_init, y_final : float
        Value before and after the move (deg); must differ.

    Returns
    -------
    dict of str to ndarray (B,)
        ``overshoot_pct``, ``undershoot_pct``, ``rise_time_s``, ``settling_time_s``, ``peak_deg``,
        ``peak_time_s``, ``steady_state_error_deg``.
    """
    y2 = np.atleast_2d(np.asarray(y, dtype=float))
    n = y2.shape[1]
    delta = y_final - y_init
    if delta == 0:
        raise ValueError("a step needs y_final != y_init")
    yn = (y2 - y_init) / delta
    rows = np.arange(y2.shape[0])

    def first_index(mask: np.ndarray) -> np.ndarray:
        hit = mask.any(axis=1)
        return np.where(hit, mask.argmax(axis=1), -1)

    lo = first_index(yn >= 0.1)
    hi = first_index(yn >= 0.9)
    rise = np.where((lo >= 0) & (hi >= 0), t_s[np.maximum(hi, 0)] - t_s[np.maximum(lo, 0)], np.inf)

    outside = np.abs(y2 - y_final) > 0.02 * abs(delta)
    any_out = outside.any(axis=1)
    last_out = n - 1 - outside[:, ::-1].argmax(axis=1)
    settled_idx = np.where(any_out, last_out + 1, 0)
    settling = np.where(settled_idx < n, t_s[np.minimum(settled_idx, n - 1)], np.inf)

    peak_idx = yn.argmax(axis=1)
    overshoot = np.maximum(0.0, 100.0 * (yn.max(axis=1) - 1.0))
    undershoot = np.maximum(0.0, -100.0 * yn.min(axis=1))
    tail = max(1, n // 10)
    sse = np.abs(y2[:, -tail:].mean(axis=1) - y_final)
    return {
        "overshoot_pct": overshoot,
        "undershoot_pct": undershoot,
        "rise_time_s": rise,
        "settling_time_s": settling,
        "peak_deg": y2[rows, peak_idx],
        "peak_time_s": t_s[peak_idx],
        "steady_state_error_deg": sse,
    }


@dataclass
class Metrics:
    """Metrics of a batch of runs (arrays of shape (B,)).

    Attributes
    ----------
    grip, ungrip : dict of str to ndarray
        Step metrics aggregated over the segments of that kind: the largest overshoot and
        undershoot, the mean of the times and errors (``inf`` if any segment never got there).
    run : dict of str to ndarray
        Run metrics (see :data:`RUN_KEYS`).
    stable : ndarray of bool
        False for diverged runs.
    """

    grip: dict[str, np.ndarray]
    ungrip: dict[str, np.ndarray]
    run: dict[str, np.ndarray]
    stable: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.stable)

    def as_dict(self, i: int = 0) -> dict[str, Any]:
        """Run ``i`` as plain Python numbers with the project's JSON keys (``inf`` kept)."""

        def part(d: dict[str, np.ndarray]) -> dict[str, float]:
            return {k: float(v[i]) for k, v in d.items() if k != "peak_time_s"}

        out: dict[str, Any] = {"grip": part(self.grip), "ungrip": part(self.ungrip)}
        out.update({k: float(v[i]) for k, v in self.run.items()})
        out["stable"] = bool(self.stable[i])
        return out


def _aggregate(parts: list[dict[str, np.ndarray]], n_runs: int) -> dict[str, np.ndarray]:
    keys = (*STEP_KEYS, "peak_time_s")
    if not parts:
        return {k: np.full(n_runs, np.inf if k != "peak_deg" else np.nan) for k in keys}
    out = {}
    for k in keys:
        stack = np.stack([p[k] for p in parts])
        if k in ("overshoot_pct", "undershoot_pct"):
            out[k] = stack.max(axis=0)
        elif k in ("peak_deg", "peak_time_s"):
            out[k] = stack[0]
        else:
            out[k] = stack.mean(axis=0)
    return out


def compute_metrics(
    traj: Any,
    signal: str = "measured",
    segments: tuple[Segment, ...] | None = None,
) -> Metrics:
    """All metrics of a :class:`~gripper_env.simulation.Trajectory` (or any object with ``t``,
    ``r``, ``u``, ``y``, ``y_true``, ``stable``, ``saturated_s`` and ``reference``).

    Parameters
    ----------
    traj : Trajectory
        Batch of runs.
    signal : {"measured", "true"}
        Score the measured angle (what an experimenter sees, the default) or the true one.
    segments : tuple of Segment, optional
        Grip/un-grip moves; default the reference's.
    """
    if signal not in ("measured", "true"):
        raise ValueError(f"signal must be 'measured' or 'true', got {signal!r}")
    y = np.atleast_2d(traj.y if signal == "measured" else traj.y_true)
    r = np.atleast_2d(traj.r)
    u = np.atleast_2d(traj.u)
    t = np.asarray(traj.t)
    n_runs = y.shape[0]
    dt = float(t[1] - t[0]) if len(t) > 1 else 1e-3
    stable = np.asarray(traj.stable, dtype=bool) & np.isfinite(y).all(axis=1)
    # diverged runs: compute on zeros, then overwrite with inf (no NaN, no warnings)
    ys = np.where(stable[:, None], y, 0.0)
    us = np.where(stable[:, None], u, 0.0)
    segs = traj.reference.segments if segments is None else segments
    grip_parts, ungrip_parts = [], []
    for seg in segs:
        if seg.stop - seg.start < 2 or seg.initial_deg == seg.final_deg:
            continue
        window = slice(seg.start, seg.stop)
        m = step_metrics(t[window] - t[seg.start], ys[:, window], seg.initial_deg, seg.final_deg)
        (grip_parts if seg.kind == "grip" else ungrip_parts).append(m)
    grip = _aggregate(grip_parts, n_runs)
    ungrip = _aggregate(ungrip_parts, n_runs)

    err = r - ys
    abs_err = np.abs(err)
    sd_y = sample_sd(ys, axis=1)
    sd_r = sample_sd(r, axis=1)
    run = {
        "sd_deg": sd_y,
        "sd_reference_deg": sd_r,
        "sd_gap_deg": np.abs(sd_r - sd_y),
        "iae": abs_err.sum(axis=1) * dt,
        "ise": (err * err).sum(axis=1) * dt,
        "itae": (abs_err * (t - t[0])).sum(axis=1) * dt,
        "control_effort": np.abs(np.diff(us, axis=1)).sum(axis=1),
        "saturation_s": np.asarray(traj.saturated_s, dtype=float) * np.ones(n_runs),
    }
    bad = ~stable
    if bad.any():
        for d in (grip, ungrip, run):
            for k in d:
                if k not in ("sd_reference_deg",):
                    d[k] = np.where(bad, math.inf, d[k])
    return Metrics(grip=grip, ungrip=ungrip, run=run, stable=stable)

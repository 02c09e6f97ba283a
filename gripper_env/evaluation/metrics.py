"""Performance metrics with MATLAB's definitions, vectorised over a batch of runs.

Definitions (DESIGN.md section 2):

* **Step metrics** (MATLAB ``stepinfo`` with ``yinit``), per grip or un-grip segment from
  ``yinit`` to ``yfinal`` with ``yn = (y - yinit) / (yfinal - yinit)``: rise time from the first
  sample with ``yn >= 0.1`` to the first with ``yn >= 0.9``; settling time = time (from the move's
  first sample) of the first sample after which ``|y - yfinal| <= 2 % |yfinal - yinit|`` for good;
  overshoot ``max(0, 100 max(yn - 1))`` % (the largest excursion past the target anywhere in
  the hold, late friction hunting included), undershoot ``max(0, -100 min(yn))`` %. The settling
  band may be given a floor in deg (``settling_band_deg``): on a gripper with stiction the jaw
  sticks anywhere within its friction band, and a 2 % band (1.4 deg on the 71 deg grip) inside
  that band would read "never settles" for every controller. Sample-based,
  without interpolation, like python-control's ``step_info``. A quantity that is never reached
  (no rise, never settles) is ``inf``, never NaN.
* **Step overshoot** (``step_overshoot_pct``, %): the overshoot of the first rise alone, on the
  true jaw angle: ``max(0, 100 (max yn - 1))`` up to the first sample after the 90 % crossing at
  which the jaw has come to rest or turned back (it moves toward the target at less than
  :data:`REST_SPEED_PER_S` of the move per second). Friction hunting late in the hold is not
  part of it: that is the **hunting** swing, ``oscillation_deg`` below (peak to peak).
* **Jaw envelope** (``jaw_min_deg``, ``jaw_max_deg``): the lowest and highest true jaw angle of
  the run, what the admission rule holds against the nearest stop the preset can draw
  (:mod:`gripper_env.evaluation.admission`); ``-inf`` / ``inf`` for a diverged run.
* **Steady-state error**: ``|mean(y) - yfinal|`` over the last 10 % of the segment (deg).
* **SD**: sample standard deviation (``ddof=1``, like MATLAB's ``std``) of the response over the
  run; **SD gap** ``|SD_reference - SD_response|``.
* **IAE, ISE, ITAE** of the tracking error ``r - y`` (deg s, deg^2 s, deg s^2), **control effort**
  = total variation of the controller output ``sum |u[k] - u[k-1]|`` (deg), **servo effort** =
  total variation of the command the servo actually received (deg; 50 Hz, whole degrees on the
  actual gripper), **saturation time** (s) with the command clipped.
* **Contact, stall and force** (from the simulation): time the jaw spent held by a mechanical
  stop or an object (s), the part of it with the servo command a whole stall band beyond (s: full
  stall current), and the mean push while held as a fraction of stall torque (0 to 1).
* **Fit %** between two responses (MATLAB ``compare``):
  ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``.

* **Sustained oscillation** (deg): the largest peak-to-peak swing of the response over a window of
  :data:`OSCILLATION_WINDOW_S` ending :data:`OSCILLATION_GUARD_S` before the end of every grip or
  un-grip segment (within its second half; the guard leaves out a controller that sees the
  profile ahead and starts the next move early). A loop with its
  command limited and its jaw between stops cannot diverge numerically: it swings from stop to
  stop for ever. Such a run is classified as diverged (``stable = False``) once its swing
  exceeds :data:`OSCILLATION_LIMIT_DEG`, well above any friction limit cycle (stick-slip hunting
  of ``S + J``, a few degrees on the presets) and far below a stop-to-stop swing.

A run flagged unstable (diverged, or oscillating) gets ``inf`` for every error-like metric and
``stable = False``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit, prange

from gripper_env.model.references import Segment
from gripper_env.sim.compile import compile_kernel
from gripper_env.sim.schedule import fetch_add, n_workers, rows_per_chunk

__all__ = [
    "OSCILLATION_LIMIT_DEG",
    "REST_SPEED_PER_S",
    "Metrics",
    "compute_metrics",
    "first_rise_overshoot",
    "fit_percent",
    "reading_band_deg",
    "sample_sd",
    "step_metrics",
    "sustained_swing",
]

STEP_KEYS = (
    "overshoot_pct",
    "undershoot_pct",
    "rise_time_s",
    "settling_time_s",
    "peak_deg",
    "steady_state_error_deg",
    "step_overshoot_pct",
)
RUN_KEYS = (
    "sd_deg",
    "sd_reference_deg",
    "sd_gap_deg",
    "iae",
    "ise",
    "itae",
    "control_effort",
    "servo_effort_deg",
    "saturation_s",
    "contact_s",
    "stall_s",
    "force_proxy",
    "oscillation_deg",
    "jaw_min_deg",
    "jaw_max_deg",
)

#: Window (s) near the end of each segment over which the sustained swing is measured.
OSCILLATION_WINDOW_S = 2.0
#: The window ends this long (s) before the segment does.
OSCILLATION_GUARD_S = 0.5
#: The jaw has come to rest after its first rise once it moves toward the target at less than
#: this fraction of the move per second (2 %/s: 1.4 deg/s on the 71 deg grip).
REST_SPEED_PER_S = 0.02
#: A run whose response still swings more than this (deg, peak to peak) at the end of a segment
#: is classified as diverged (see the module docstring).
OSCILLATION_LIMIT_DEG = 8.0


def reading_band_deg(y: np.ndarray, resolution_deg: float) -> tuple[float, float]:
    """What a measured angle's own resolution and noise leave of a settling band (deg).

    A reading quantized to ``resolution_deg`` (an ADC count) and noisy flickers around a jaw at
    rest: a settling band narrower than that flicker reads "never settles" for a jaw that has
    (the rig printed "settling 8.98 s" where its plot showed the jaw settled within 0.5 s).
    The noise is estimated from the sample-to-sample steps of the reading no larger than four
    counts (the jaw at rest or nearly so; a move's steps are left out): ``sigma = rms(step) /
    sqrt(2)``, the noise of one sample if the steps were noise alone (an upper estimate).

    Parameters
    ----------
    y : ndarray
        The measured angle of one run (deg), NaN where a sample is missing.
    resolution_deg : float
        One step of the reading (deg per ADC count).

    Returns
    -------
    band_deg : float
        ``resolution_deg + 3 sigma``: how far a reading of a jaw at rest may stray.
    noise_sd_deg : float
        ``sigma``.
    """
    if not (math.isfinite(resolution_deg) and resolution_deg >= 0):
        raise ValueError(f"resolution_deg must be a number >= 0, got {resolution_deg!r}")
    steps = np.diff(np.asarray(y, dtype=float).ravel())
    steps = steps[np.isfinite(steps)]
    small = steps[np.abs(steps) <= 4.0 * resolution_deg + 1e-12]
    sigma = float(np.sqrt(np.mean(small**2) / 2.0)) if small.size else 0.0
    return resolution_deg + 3.0 * sigma, sigma


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


# Columns of the per-segment result of the compiled kernel.
_SEG_COLUMNS = (
    "overshoot_pct",
    "undershoot_pct",
    "rise_time_s",
    "settling_time_s",
    "peak_deg",
    "peak_time_s",
    "steady_state_error_deg",
)


@njit(cache=True)
def _segment(
    t: np.ndarray, y: np.ndarray, start: int, stop: int, y_init: float, y_final: float,
    band_floor: float, out: np.ndarray,
) -> None:  # fmt: skip
    """Step metrics of ``y[start:stop]`` (one run), written into ``out`` (see _SEG_COLUMNS)."""
    delta = y_final - y_init
    band = max(0.02 * abs(delta), band_floor)
    t0 = t[start]
    lo_idx = -1
    hi_idx = -1
    yn_max = -np.inf
    yn_min = np.inf
    peak = start
    for k in range(start, stop):
        yn = (y[k] - y_init) / delta
        if lo_idx < 0 and yn >= 0.1:
            lo_idx = k
        if hi_idx < 0 and yn >= 0.9:
            hi_idx = k
        if yn > yn_max:
            yn_max = yn
            peak = k
        if yn < yn_min:
            yn_min = yn
    settled = start
    for k in range(stop - 1, start - 1, -1):
        if abs(y[k] - y_final) > band:
            settled = k + 1
            break
    n = stop - start
    tail = max(1, n // 10)
    acc = 0.0
    for k in range(stop - tail, stop):
        acc += y[k]
    out[0] = max(0.0, 100.0 * (yn_max - 1.0))
    out[1] = max(0.0, -100.0 * yn_min)
    out[2] = t[hi_idx] - t[lo_idx] if (lo_idx >= 0 and hi_idx >= 0) else np.inf
    out[3] = t[settled] - t0 if settled < stop else np.inf
    out[4] = y[peak]
    out[5] = t[peak] - t0
    out[6] = abs(acc / tail - y_final)


@njit(cache=True)
def _run(
    t: np.ndarray,
    r: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    seg_bounds: np.ndarray,
    seg_values: np.ndarray,
    band_floor: float,
    run_out: np.ndarray,
    seg_out: np.ndarray,
) -> None:
    """Metrics of one run (1-D ``r``, ``y``, ``u``) into ``run_out`` and ``seg_out``."""
    n = y.shape[0]
    dt = t[1] - t[0] if n > 1 else 0.0
    iae = 0.0
    ise = 0.0
    itae = 0.0
    effort = 0.0
    sum_y = 0.0
    sum_r = 0.0
    for k in range(n):
        e = r[k] - y[k]
        ae = abs(e)
        iae += ae
        ise += e * e
        itae += (t[k] - t[0]) * ae
        sum_y += y[k]
        sum_r += r[k]
        if k > 0:
            effort += abs(u[k] - u[k - 1])
    mean_y = sum_y / n
    mean_r = sum_r / n
    var_y = 0.0
    var_r = 0.0
    for k in range(n):
        dy = y[k] - mean_y
        dr = r[k] - mean_r
        var_y += dy * dy
        var_r += dr * dr
    run_out[0] = iae * dt
    run_out[1] = ise * dt
    run_out[2] = itae * dt
    run_out[3] = effort
    run_out[4] = mean_y
    run_out[5] = math.sqrt(var_y / (n - 1)) if n > 1 else 0.0
    run_out[6] = math.sqrt(var_r / (n - 1)) if n > 1 else 0.0
    for s in range(seg_bounds.shape[0]):
        _segment(
            t, y, seg_bounds[s, 0], seg_bounds[s, 1], seg_values[s, 0], seg_values[s, 1],
            band_floor, seg_out[s],
        )  # fmt: skip


def _metrics_impl(
    t: np.ndarray,
    r: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    seg_bounds: np.ndarray,
    seg_values: np.ndarray,
    band_floor: float,
    run_out: np.ndarray,
    seg_out: np.ndarray,
) -> None:
    """One pass per run (parallel over runs, :mod:`gripper_env.sim.schedule`); ``r`` is (1 or B, T).

    Run columns: IAE, ISE, ITAE, control effort, mean of y, SD of y, SD of r.
    """
    n_runs = y.shape[0]
    shared = r.shape[0] == 1
    chunk = rows_per_chunk(y.shape[1])
    n_chunks = (n_runs + chunk - 1) // chunk
    counter = np.zeros(1, np.int64)
    for _ in prange(n_workers(n_chunks)):
        c = fetch_add(counter, np.int64(1))
        while c < n_chunks:
            for b in range(c * chunk, min(n_runs, (c + 1) * chunk)):
                r_row = r[0] if shared else r[b]
                _run(
                    t, r_row, y[b], u[b], seg_bounds, seg_values, band_floor, run_out[b],
                    seg_out[b],
                )  # fmt: skip
            c = fetch_add(counter, np.int64(1))


_metrics_serial, _metrics_parallel = compile_kernel(_metrics_impl)
#: Batches at least this large are scored on all cores (threads cost more for a few runs).
PARALLEL_MIN_BATCH = 16


def _metrics_kernel(*args: Any) -> None:
    kernel = _metrics_parallel if args[2].shape[0] >= PARALLEL_MIN_BATCH else _metrics_serial
    kernel(*args)


def step_metrics(
    t_s: np.ndarray,
    y: np.ndarray,
    y_init: float,
    y_final: float,
    settling_band_deg: float = 0.0,
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
    settling_band_deg : float
        Floor of the settling band (deg); the band is ``max(2 % |y_final - y_init|, floor)``.

    Returns
    -------
    dict of str to ndarray (B,)
        ``overshoot_pct``, ``undershoot_pct``, ``rise_time_s``, ``settling_time_s``, ``peak_deg``,
        ``peak_time_s``, ``steady_state_error_deg``.
    """
    if y_final == y_init:
        raise ValueError("a step needs y_final != y_init")
    y2 = np.ascontiguousarray(np.atleast_2d(np.asarray(y, dtype=float)))
    t = np.ascontiguousarray(t_s, dtype=float)
    n_runs, n = y2.shape
    run_out = np.empty((n_runs, 7))
    seg_out = np.empty((n_runs, 1, len(_SEG_COLUMNS)))
    _metrics_kernel(
        t, y2, y2, y2, np.array([[0, n]]), np.array([[y_init, y_final]], dtype=float),
        float(settling_band_deg), run_out, seg_out,
    )  # fmt: skip
    return {name: seg_out[:, 0, i] for i, name in enumerate(_SEG_COLUMNS)}


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
        False for diverged runs and runs in sustained oscillation.
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
            return {k: float(v[i]) for k, v in d.items()}

        out: dict[str, Any] = {"grip": part(self.grip), "ungrip": part(self.ungrip)}
        out.update({k: float(v[i]) for k, v in self.run.items()})
        out["stable"] = bool(self.stable[i])
        return out


def sustained_swing(
    y: np.ndarray, segments: Any, dt_s: float, reference: np.ndarray | None = None
) -> np.ndarray:
    """Largest peak-to-peak swing (deg) of each run over a window of :data:`OSCILLATION_WINDOW_S`
    ending :data:`OSCILLATION_GUARD_S` before the end of every segment (within its second
    half); 0 without segments.

    Parameters
    ----------
    y : ndarray, shape (B, n)
        Responses (deg).
    segments : sequence of Segment
        The moves; each spans from its start to the next move.
    dt_s : float
        Sample time (s).
    reference : ndarray, shape (B, n) or (1, n), optional
        The reference: the swing is then that of the tracking error ``y - r``, so a ramp still
        running in the window (a random profile's moves are ramps of up to 5 s) is not taken
        for an oscillation. Over a hold (every window of the step profiles) the two agree.
    """
    if reference is not None:
        y = y - np.asarray(reference, dtype=float)
    swing = np.zeros(y.shape[0])
    guard = round(OSCILLATION_GUARD_S / dt_s)
    for seg in segments:
        half = (seg.stop - seg.start) // 2
        end = seg.stop - min(guard, half // 2)
        n = min(round(OSCILLATION_WINDOW_S / dt_s), end - (seg.start + half))
        if n < 2:
            continue
        window = y[:, end - n : end]
        swing = np.maximum(swing, window.max(axis=1) - window.min(axis=1))
    return swing


def first_rise_overshoot(y: np.ndarray, y_init: float, y_final: float, dt_s: float) -> np.ndarray:
    """Overshoot (%) of the first rise of each response ``y`` (B, n) to one move (see
    ``step_overshoot_pct`` in the module docstring); 0 for a response that never reaches 90 %.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(0, 4, 1e-3)
    >>> y = np.where(t < 1, 10 * t, 10.0)  # a ramp that stops at its target
    >>> y = y + np.where((t > 2) & (t < 3), 1.0, 0.0)  # a late creep past it
    >>> float(first_rise_overshoot(y[None, :], 0.0, 10.0, 1e-3)[0])
    0.0
    """
    y = np.atleast_2d(np.asarray(y, dtype=float))
    yn = (y - y_init) / (y_final - y_init)
    n_runs, n = yn.shape
    if n < 2:
        return np.zeros(n_runs)
    reached = yn >= 0.9
    i90 = np.where(reached.any(axis=1), reached.argmax(axis=1), n)
    rest = np.diff(yn, axis=1) <= REST_SPEED_PER_S * dt_s
    rest &= np.arange(n - 1)[None, :] >= i90[:, None]
    end = np.where(rest.any(axis=1), rest.argmax(axis=1), n - 1)
    peak = np.maximum.accumulate(yn, axis=1)[np.arange(n_runs), end]
    return np.where(i90 < n, np.maximum(0.0, 100.0 * (peak - 1.0)), 0.0)


def _aggregate(parts: list[dict[str, np.ndarray]], n_runs: int) -> dict[str, np.ndarray]:
    keys = (*_SEG_COLUMNS, "step_overshoot_pct")
    if not parts:
        return {k: np.full(n_runs, np.inf) for k in keys}
    out = {}
    for k in keys:
        stack = np.stack([p[k] for p in parts])
        if k in ("overshoot_pct", "undershoot_pct", "step_overshoot_pct"):
            out[k] = stack.max(axis=0)
        elif k in ("peak_deg", "peak_time_s"):
            out[k] = stack[0]
        else:
            out[k] = stack.mean(axis=0)
    return out


def _counter(traj: Any, name: str, n_runs: int) -> np.ndarray:
    """A per-run counter of the trajectory (NaN if it has none)."""
    value = getattr(traj, name, None)
    if value is None:
        return np.full(n_runs, np.nan)
    return np.asarray(value, dtype=float) * np.ones(n_runs)


def compute_metrics(
    traj: Any,
    signal: str = "measured",
    segments: tuple[Segment, ...] | None = None,
    settling_band_deg: float = 0.0,
) -> Metrics:
    """All metrics of a :class:`~gripper_env.sim.Trajectory` (or any object with ``t``,
    ``r``, ``u``, ``y``, ``y_true``, ``stable``, ``saturated_s`` and ``reference``).

    Parameters
    ----------
    traj : Trajectory
        Batch of runs.
    signal : {"measured", "true"}
        Score the measured angle (what an experimenter sees, the default) or the true one.
    segments : tuple of Segment, optional
        Grip/un-grip moves; default the reference's.
    settling_band_deg : float
        Floor of the settling band (deg); the band is ``max(2 % of the move, floor)``.

    The contact, stall, force and servo-effort metrics come from the trajectory's counters
    (:meth:`~gripper_env.sim.BatchSimulator.trajectory`); NaN where it has none.
    """
    if signal not in ("measured", "true"):
        raise ValueError(f"signal must be 'measured' or 'true', got {signal!r}")
    y = np.atleast_2d(traj.y if signal == "measured" else traj.y_true)
    r = np.ascontiguousarray(np.atleast_2d(traj.r), dtype=float)
    u = np.atleast_2d(traj.u)
    t = np.ascontiguousarray(traj.t, dtype=float)
    n_runs = y.shape[0]
    stable = np.asarray(traj.stable, dtype=bool) & np.isfinite(y).all(axis=1)
    # diverged runs: compute on zeros, then overwrite with inf (no NaN, no warnings)
    if stable.all():
        ys, us = np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(u, dtype=float)
    else:
        ys = np.ascontiguousarray(np.where(stable[:, None], y, 0.0))
        us = np.ascontiguousarray(np.where(stable[:, None], u, 0.0))
    if np.all(r == r[:1]):
        r = r[:1]
    segs = [
        s
        for s in (traj.reference.segments if segments is None else segments)
        if s.stop - s.start >= 2 and s.initial_deg != s.final_deg
    ]
    bounds = np.array([[s.start, s.stop] for s in segs], dtype=np.int64).reshape(-1, 2)
    values = np.array([[s.initial_deg, s.final_deg] for s in segs], dtype=float).reshape(-1, 2)
    run_out = np.empty((n_runs, 7))
    seg_out = np.empty((n_runs, len(segs), len(_SEG_COLUMNS)))
    if not math.isfinite(settling_band_deg) or settling_band_deg < 0:
        raise ValueError(f"settling_band_deg must be >= 0, got {settling_band_deg!r}")
    _metrics_kernel(t, r, ys, us, bounds, values, float(settling_band_deg), run_out, seg_out)
    parts: dict[str, list[dict[str, np.ndarray]]] = {"grip": [], "ungrip": []}
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    y_true = getattr(traj, "y_true", None)
    jaw = np.atleast_2d(np.asarray(y if y_true is None else y_true, dtype=float))
    jaw = np.where(stable[:, None], jaw, 0.0)
    for i, s in enumerate(segs):
        part = {name: seg_out[:, i, j] for j, name in enumerate(_SEG_COLUMNS)}
        part["step_overshoot_pct"] = first_rise_overshoot(
            jaw[:, s.start : s.stop], s.initial_deg, s.final_deg, dt
        )
        parts[s.kind].append(part)
    grip = _aggregate(parts["grip"], n_runs)
    ungrip = _aggregate(parts["ungrip"], n_runs)
    sd_y, sd_r = run_out[:, 5], run_out[:, 6]
    run = {
        "sd_deg": sd_y,
        "sd_reference_deg": sd_r,
        "sd_gap_deg": np.abs(sd_r - sd_y),
        "iae": run_out[:, 0],
        "ise": run_out[:, 1],
        "itae": run_out[:, 2],
        "control_effort": run_out[:, 3],
        "servo_effort_deg": _counter(traj, "servo_effort_deg", n_runs),
        "saturation_s": np.asarray(traj.saturated_s, dtype=float) * np.ones(n_runs),
        "contact_s": _counter(traj, "contact_s", n_runs),
        "stall_s": _counter(traj, "stall_s", n_runs),
        "force_proxy": _counter(traj, "force_proxy", n_runs),
        "oscillation_deg": sustained_swing(ys, segs, dt, reference=r),
        "jaw_min_deg": jaw.min(axis=1),
        "jaw_max_deg": jaw.max(axis=1),
    }
    oscillating = run["oscillation_deg"] > OSCILLATION_LIMIT_DEG
    stable = stable & ~oscillating
    bad = ~stable
    if bad.any():
        for d in (grip, ungrip, run):
            for k in d:
                if k not in ("sd_reference_deg", "oscillation_deg"):
                    d[k] = np.where(bad, math.inf, d[k])
        run["jaw_min_deg"] = np.where(bad, -math.inf, run["jaw_min_deg"])
    return Metrics(grip=grip, ungrip=ungrip, run=run, stable=stable)

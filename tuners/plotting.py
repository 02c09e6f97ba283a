"""Figures: a controller's response (like the paper's Figure 11) and the benchmark's plots.

matplotlib with the Agg backend (no display needed); every figure is written atomically
(:func:`gripper_env.io.files.save_figure`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

from gripper_env.evaluation.metrics import step_metrics
from gripper_env.io.files import save_figure
from gripper_env.model.references import Segment

__all__ = [
    "StepZoom",
    "budget_plot",
    "grasp_plot",
    "learning_curve_plot",
    "median_seed",
    "metrics_table",
    "pareto_plot",
    "response_figure",
    "response_plot",
    "step_zooms",
]


#: Most moves that get a zoom of their own (the step profile has two: the grip and the un-grip);
#: a longer profile gets a zoom on its first grip and its first un-grip.
MAX_ZOOMS = 4
#: The zoom starts this long before the move (s): before a step; before a ramp's end (or
#: before it settled, if earlier).
ZOOM_BEFORE_S = 0.05
#: The zoom ends this many times the later settling time (model or median seed) after the
#: reference arrived, at least :data:`ZOOM_MIN_S`, at most :data:`ZOOM_MAX_S` after it (a
#: later settling, a wobble out of the band long after the transient, is marked at the zoom's
#: edge), and within the segment.
ZOOM_SETTLING_FACTOR = 1.3
ZOOM_MIN_S = 0.3
ZOOM_MAX_S = 2.0
#: The servo's command range (deg): what ``Servo.write`` accepts.
SERVO_RANGE_DEG = (0.0, 180.0)
#: An overshoot (%) below this is printed as 0.00 and its peak is not marked.
PEAK_MIN_PCT = 0.005

_REF, _MODEL, _ACTUAL, _BAND, _LIMIT = "k", "tab:blue", "tab:orange", "tab:green", "tab:red"


@dataclass(frozen=True)
class StepZoom:
    """What the zoom on one move shows, with the project's step metrics of that move
    (:func:`gripper_env.evaluation.metrics.step_metrics`, the function the evaluation uses).

    Attributes
    ----------
    segment : Segment
        The move (sample indices, initial and final reference in deg, kind).
    window_s : tuple of float
        The zoom's time span, from the move's first sample (s).
    arrive_s : float
        When the reference reaches its final value, from the move's first sample (s): 0 for a
        step, the ramp's length for a ramp (the zoom is on its end).
    band_deg, model_band_deg : float
        Half-widths of the settling bands around the final value (deg): the actual model's
        (``max(2 %, the objective's floor on its preset)``) and the model's (on the ``ideal``
        preset, usually 2 % of the move).
    model : dict of str to float
        The model's step metrics of this move (``overshoot_pct``, ``rise_time_s``,
        ``settling_time_s``, ``peak_deg``, ``peak_time_s``, ...; ``inf`` = never).
    actual : dict of str to ndarray
        The same per held-out seed (``inf`` for a seed whose run the evaluation found unstable).
    actual_mean : dict of str to float
        Their mean over the seeds (``inf`` if any seed is), as the evaluation summarises them.
    median_seed : int
        Row of the median seed (by IAE) in the actual trajectory.
    model_marks, median_marks : dict of str to float
        Times from the move (s) of the 10 % and 90 % crossings (``t10_s``, ``t90_s``), of the
        peak and of settling, for the model and the median seed (NaN where there is none).
    """

    segment: Segment
    window_s: tuple[float, float]
    arrive_s: float
    band_deg: float
    model_band_deg: float
    model: dict[str, float]
    actual: dict[str, np.ndarray]
    actual_mean: dict[str, float]
    median_seed: int
    model_marks: dict[str, float]
    median_marks: dict[str, float]


def _signal(traj: Any, signal: str) -> np.ndarray:
    return np.atleast_2d(traj.y_true if signal == "true" else traj.y)


def median_seed(evaluation: Any) -> int:
    """Row of the seed with the median IAE over the run (the evaluation's), diverged runs last."""
    iae = np.array([run.get("iae", math.inf) for run in evaluation.actual_runs], dtype=float)
    iae = np.where(np.isfinite(iae), iae, np.inf)
    return int(np.argsort(iae, kind="stable")[len(iae) // 2])


def _zoomed_segments(segments: Sequence[Segment]) -> list[Segment]:
    """The moves to zoom on: every one of up to :data:`MAX_ZOOMS`, else the first of each kind."""
    moves = [s for s in segments if s.stop - s.start >= 2 and s.initial_deg != s.final_deg]
    if len(moves) <= MAX_ZOOMS:
        return moves
    first = {s.kind: s for s in reversed(moves)}
    return [s for s in moves if first.get(s.kind) is s]


def _marks(t_s: np.ndarray, y: np.ndarray, seg: Segment, m: dict[str, float]) -> dict[str, float]:
    """Times (from the move) of the first samples at 10 % and 90 % of the move (the samples
    :func:`~gripper_env.evaluation.metrics.step_metrics` takes the rise time between), of the
    peak (NaN below :data:`PEAK_MIN_PCT` of overshoot) and of settling (NaN: never)."""
    yn = (y - seg.initial_deg) / (seg.final_deg - seg.initial_deg)
    out = {}
    for key, level in (("t10_s", 0.1), ("t90_s", 0.9)):
        hit = np.flatnonzero(yn >= level)
        out[key] = float(t_s[hit[0]]) if hit.size else math.nan
    # the peak is the overshoot's: none when it reads 0.00 %
    out["peak_s"] = float(m["peak_time_s"]) if m["overshoot_pct"] >= PEAK_MIN_PCT else math.nan
    out["settled_s"] = (
        float(m["settling_time_s"]) if np.isfinite(m["settling_time_s"]) else math.nan
    )
    return out


def step_zooms(
    evaluation: Any,
    settling_band_deg: float = 0.0,
    model_settling_band_deg: float = 0.0,
    signal: str = "true",
) -> list[StepZoom]:
    """The zooms of :func:`response_plot`: one per move (see :data:`MAX_ZOOMS`) with its window,
    its settling bands and its step metrics.

    Parameters
    ----------
    evaluation : tuners.evaluation.Evaluation
        Trajectories and metrics.
    settling_band_deg : float
        The objective's settling-band floor on the actual model's preset (deg).
    model_settling_band_deg : float
        The same on the ``ideal`` preset the model is scored on (deg; 0 for the shipped one).
    signal : {"true", "measured"}
        The objective's signal: the jaw angle the metrics score.
    """
    ideal, actual = evaluation.ideal_trajectory, evaluation.actual_trajectory
    t = np.asarray(ideal.t, dtype=float)
    y_model = _signal(ideal, signal)[0]
    y = _signal(actual, signal)
    stable = np.array([bool(run.get("stable", True)) for run in evaluation.actual_runs])
    stable &= np.isfinite(y).all(axis=1)
    med = median_seed(evaluation)
    zooms = []
    for seg in _zoomed_segments(ideal.reference.segments):
        ts = t[seg.start : seg.stop] - t[seg.start]
        move = seg.final_deg - seg.initial_deg
        band = max(0.02 * abs(move), settling_band_deg)
        model_band = max(0.02 * abs(move), model_settling_band_deg)
        ym = y_model[seg.start : seg.stop]
        if np.isfinite(ym).all() and bool(evaluation.ideal.get("stable", True)):
            m = {k: float(v[0]) for k, v in step_metrics(ts, ym, seg.initial_deg, seg.final_deg,
                                                         model_band).items()}  # fmt: skip
        else:
            m = {k: math.inf for k in ("overshoot_pct", "rise_time_s", "settling_time_s")}
            m.update(peak_deg=math.nan, peak_time_s=math.nan)
        rows = np.where(stable[:, None], y[:, seg.start : seg.stop], 0.0)
        per = step_metrics(ts, rows, seg.initial_deg, seg.final_deg, band)
        per = {k: np.where(stable, v, math.inf) for k, v in per.items()}
        mean = {k: float(v.mean()) if np.isfinite(v).all() else math.inf for k, v in per.items()}
        model_marks = (_marks(ts, ym, seg, m) if np.isfinite(m["rise_time_s"])
                       or np.isfinite(m["settling_time_s"]) else {})  # fmt: skip
        med_m = {k: float(v[med]) for k, v in per.items()}
        median_marks = _marks(ts, y[med, seg.start : seg.stop], seg, med_m) if stable[med] else {}
        settled = [d.get("settled_s", math.nan) for d in (model_marks, median_marks)]
        settled = [s for s in settled if np.isfinite(s)]
        # a step arrives at once; a ramp at its end, where the overshoot and settling are
        arrived = np.flatnonzero(np.isclose(ideal.r[0, seg.start : seg.stop], seg.final_deg))
        arrive = float(ts[arrived[0]]) if arrived.size else 0.0
        start = min([arrive, *settled]) - ZOOM_BEFORE_S
        start = max(start, -(t[seg.start] - t[0]))
        span = ts[-1]
        late = ZOOM_SETTLING_FACTOR * (max(settled, default=span) - arrive)
        end = min(span, arrive + ZOOM_MAX_S, arrive + max(ZOOM_MIN_S, late))
        zooms.append(StepZoom(seg, (float(start), float(end)), float(arrive), float(band),
                              float(model_band), m, per, mean, med, model_marks,
                              median_marks))  # fmt: skip
    return zooms


def _ms(x: float) -> str:
    """A time (s) in ms for a label: ``never`` for inf."""
    if not np.isfinite(x):
        return "never" if x > 0 else "-"
    return f"{1e3 * x:.0f}" if abs(x) >= 0.1 else f"{1e3 * x:.3g}"


def _pct(x: float) -> str:
    """An overshoot (%) for a label."""
    if not np.isfinite(x):
        return "-" if np.isnan(x) else "inf"
    return f"{x:.2f}" if abs(x) < 10 else f"{x:.1f}"


def metrics_table(zoom: StepZoom) -> str:
    """The text of a zoom's metrics box: the model's value and the actual model's mean over the
    seeds (with their range), each as :func:`step_zooms` has it."""
    n = len(zoom.actual["overshoot_pct"])
    rows = [f"{'':12s}{'model':>7s}  actual, {n} seed{'s' if n > 1 else ''}",
            f"{'':12s}{'':>7s}  {'mean (min-max)' if n > 1 else ''}"]  # fmt: skip
    for key, label, fmt in (("overshoot_pct", "overshoot %", _pct),
                            ("rise_time_s", "rise ms", _ms),
                            ("settling_time_s", "settling ms", _ms)):  # fmt: skip
        values = zoom.actual[key]
        spread = ""
        if n > 1 and np.isfinite(values).all():
            spread = f" ({fmt(float(values.min()))}-{fmt(float(values.max()))})"
        rows.append(f"{label:12s}{fmt(zoom.model[key]):>7s}  {fmt(zoom.actual_mean[key])}{spread}")
    rows.append(f"{'band deg':12s}{'±' + format(zoom.model_band_deg, '.3g'):>7s}  "
                f"±{zoom.band_deg:.3g}")  # fmt: skip
    bad = int(np.sum(~np.isfinite(zoom.actual["overshoot_pct"])))  # only unstable runs' is inf
    if bad:
        rows.append(f"{bad} of {n} seeds unstable: inf")
    return "\n".join(rows)


def _ylim(ax: Any, lo: float, hi: float, ref_lo: float, ref_hi: float) -> str:
    """Set the response axis to ``[lo, hi]`` padded, capped at a move's height beyond the
    reference (a diverging model would flatten everything else); return a note if capped."""
    span = max(ref_hi - ref_lo, 1.0)
    cap_lo, cap_hi = ref_lo - span, ref_hi + span
    a, b = max(lo, cap_lo), min(hi, cap_hi)
    pad = 0.05 * (b - a)
    ax.set_ylim(a - pad, b + pad)
    return (f"axis capped: the response reaches {lo:.0f} to {hi:.0f} deg"
            if lo < cap_lo or hi > cap_hi else "")  # fmt: skip


def _nan_range(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.min(rows, axis=0), np.max(rows, axis=0)


def response_figure(
    evaluation: Any,
    title: str,
    settling_band_deg: float = 0.0,
    *,
    model_settling_band_deg: float = 0.0,
    signal: str = "true",
) -> Any:
    """The figure of :func:`response_plot` (a matplotlib Figure; axes labelled ``overview``,
    ``zoom <i>``, ``command zoom <i>`` and ``command``)."""
    ideal, actual = evaluation.ideal_trajectory, evaluation.actual_trajectory
    t = np.asarray(ideal.t, dtype=float)
    ref = np.asarray(ideal.r[0], dtype=float)
    y_model = _signal(ideal, signal)[0]
    y = _signal(actual, signal)
    u_model = np.atleast_2d(ideal.u)[0]
    u = np.atleast_2d(actual.u)
    finite = np.isfinite(y).all(axis=1) & np.isfinite(u).all(axis=1)
    unstable = sum(not run.get("stable", True) for run in evaluation.actual_runs)
    zooms = step_zooms(evaluation, settling_band_deg, model_settling_band_deg, signal)
    med = median_seed(evaluation)
    n_ok, n_all = int(finite.sum()), len(finite)
    seeds = evaluation.seeds
    cols = max(1, len(zooms))
    fig = plt.figure(figsize=(11, 10.2))
    grid = fig.add_gridspec(3, 1, height_ratios=[2.0, 3.9, 1.0], hspace=0.28)
    pairs = grid[1].subgridspec(2, cols, height_ratios=[2.6, 1.2], hspace=0.07, wspace=0.2)
    ref_lo, ref_hi = float(np.min(ref)), float(np.max(ref))
    act_label = f"actual model, min-max of {n_ok} seeds"
    if n_ok < n_all:
        act_label += f" ({n_all - n_ok} diverged, not drawn)"
    if unstable:
        act_label += f"; {unstable} of {n_all} unstable (metrics inf)"
    med_label = f"actual model, median seed by IAE ({seeds[med] if med < len(seeds) else med})"

    # overview: the whole run, the zoom windows lettered
    ax = fig.add_subplot(grid[0], label="overview")
    ax.plot(t, ref, color=_REF, lw=1.0, ls="--", label="reference")
    if n_ok:
        lo, hi = _nan_range(y[finite])
        ax.fill_between(t, lo, hi, color=_ACTUAL, alpha=0.3, lw=0, label=act_label)
    if finite[med]:
        ax.plot(t, y[med], color=_ACTUAL, lw=0.9, label=med_label)
    ax.plot(t, y_model, color=_MODEL, lw=1.1, label="model (ideal TF)")
    for i, z in enumerate(zooms):
        t0 = t[z.segment.start]
        ax.axvspan(t0 + z.window_s[0], t0 + z.window_s[1], color="0.5", alpha=0.18, lw=0)
        ax.annotate(chr(ord("A") + i), (t0 + z.window_s[1], 1.0),
                    xycoords=("data", "axes fraction"), xytext=(2, -2),
                    textcoords="offset points", va="top", fontsize=9,
                    fontweight="bold")  # fmt: skip
    finite_y = np.concatenate([y[finite].ravel(), y_model[np.isfinite(y_model)], ref])
    note = _ylim(ax, float(finite_y.min()), float(finite_y.max()), ref_lo, ref_hi)
    if note:
        ax.text(0.01, 0.02, note, transform=ax.transAxes, fontsize=7, color="0.3")
    ax.set_ylabel(f"jaw angle, {signal} (deg)")
    ax.set_xlabel("time (s); shaded: the zooms A, B, ...", fontsize=8)
    ax.grid(alpha=0.3)
    ax.tick_params(labelsize=8)

    for i, z in enumerate(zooms):
        axz = fig.add_subplot(pairs[0, i], label=f"zoom {i}")
        axu = fig.add_subplot(pairs[1, i], sharex=axz, label=f"command zoom {i}")
        _draw_zoom(axz, axu, chr(ord("A") + i), z, t, ref, y, y_model, u, u_model, finite)

    # the command over the whole run, unclipped, with the servo's range
    axc = fig.add_subplot(grid[2], sharex=ax, label="command")
    if n_ok:
        lo, hi = _nan_range(u[finite])
        axc.fill_between(t, lo, hi, color=_ACTUAL, alpha=0.3, lw=0)
    if finite[med]:
        axc.plot(t, u[med], color=_ACTUAL, lw=0.6)
    axc.plot(t, u_model, color=_MODEL, lw=0.8)
    _servo_range(axc, np.concatenate([u[finite].ravel(), u_model[np.isfinite(u_model)]]))
    sat = (evaluation.actual.get("mean") or {}).get("saturation_s", math.nan)
    sat_text = (f"{_ms(sat)} ms per run (mean)" if np.isfinite(sat)
                else "inf: unstable runs" if sat > 0 else "-")  # fmt: skip
    axc.text(0.995, 0.97, f"actual: at the servo's limit {sat_text}",
             transform=axc.transAxes, ha="right", va="top", fontsize=7,
             bbox={"fc": "white", "ec": "none", "alpha": 0.8, "pad": 1})  # fmt: skip
    axc.set_xlabel("time (s)")
    axc.set_ylabel("command (deg)", fontsize=9)
    axc.grid(alpha=0.3)
    axc.tick_params(labelsize=8)

    handles = [
        Line2D([], [], color=_REF, ls="--", lw=1.0, label="reference"),
        Line2D([], [], color=_MODEL, lw=1.2, label="model (ideal TF)"),
        Line2D([], [], color=_ACTUAL, lw=1.2, label=med_label),
        Patch(color=_ACTUAL, alpha=0.3, lw=0, label=act_label),
        Patch(color=_BAND, alpha=0.2, lw=0, label="settling band, actual (shaded)"),
        Line2D([], [], color=_MODEL, ls=(0, (5, 2)), lw=0.8, label="settling band, model"),
        Line2D([], [], color="0.45", ls="-.", lw=0.6, label="10 % and 90 % of the move"),
        Line2D(
            [],
            [],
            color="0.3",
            marker="o",
            ls="none",
            ms=4,
            mfc="white",
            label="10 % / 90 % crossings (rise)",
        ),
        Line2D([], [], color="0.3", marker="D", ls="none", ms=4, label="peak (overshoot)"),
        Line2D([], [], color="0.3", ls=":", lw=1.0, label="settled for good"),
        Line2D([], [], color=_LIMIT, ls=":", lw=1.0, label="servo range 0-180 deg (beyond: red)"),
    ]
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.975), ncol=4,
               fontsize=7.5, frameon=False, handlelength=2.4,
               columnspacing=1.5)  # fmt: skip
    fig.suptitle(title, fontsize=10, y=0.995)
    fig.subplots_adjust(top=0.895, bottom=0.05, left=0.065, right=0.99)
    return fig


def _servo_range(ax: Any, values: np.ndarray) -> None:
    """Mark the servo's range and show all of ``values`` and the range (nothing clipped)."""
    lo_s, hi_s = SERVO_RANGE_DEG
    for edge in SERVO_RANGE_DEG:
        ax.axhline(edge, color=_LIMIT, lw=0.8, ls=":")
    lo = min(lo_s, float(values.min())) if values.size else lo_s
    hi = max(hi_s, float(values.max())) if values.size else hi_s
    pad = 0.06 * (hi - lo)
    ax.set_ylim(lo - pad, hi + pad)
    for a, b in ((lo - pad, lo_s), (hi_s, hi + pad)):  # beyond the servo's range
        ax.axhspan(a, b, color=_LIMIT, alpha=0.04, lw=0)


def _draw_zoom(
    ax: Any, axu: Any, letter: str, z: StepZoom, t: np.ndarray, ref: np.ndarray, y: np.ndarray,
    y_model: np.ndarray, u: np.ndarray, u_model: np.ndarray, finite: np.ndarray,
) -> None:  # fmt: skip
    """One move, zoomed: response with bands, levels, marks and the metrics box; command."""
    seg = z.segment
    dt = float(t[1] - t[0])
    i0 = max(0, seg.start + math.floor(z.window_s[0] / dt + 1e-9))
    i1 = min(len(t), seg.start + math.ceil(z.window_s[1] / dt + 1e-9) + 1)
    tz = t[i0:i1] - t[seg.start]
    move = seg.final_deg - seg.initial_deg
    final = seg.final_deg
    ax.axhspan(final - z.band_deg, final + z.band_deg, color=_BAND, alpha=0.2, lw=0,
               label="settling band")  # fmt: skip
    if not math.isclose(z.model_band_deg, z.band_deg):
        for edge in (final - z.model_band_deg, final + z.model_band_deg):
            ax.axhline(edge, color=_MODEL, ls=(0, (5, 2)), lw=0.8)
    for level in (0.1, 0.9):
        ax.axhline(seg.initial_deg + level * move, color="0.45", ls="-.", lw=0.6)
    ax.plot(tz, ref[i0:i1], color=_REF, lw=1.0, ls="--")
    med = z.median_seed
    if finite.any():
        lo, hi = _nan_range(y[finite, i0:i1])
        ax.fill_between(tz, lo, hi, color=_ACTUAL, alpha=0.3, lw=0)
    if finite[med]:
        ax.plot(tz, y[med, i0:i1], color=_ACTUAL, lw=1.3)
    ax.plot(tz, y_model[i0:i1], color=_MODEL, lw=1.3)
    notes: list[str] = []
    for marks, color, yy, who in ((z.model_marks, _MODEL, y_model, "model"),
                                  (z.median_marks, _ACTUAL, y[med], "median seed")):  # fmt: skip
        if not marks:
            continue
        for key in ("t10_s", "t90_s"):
            if np.isfinite(marks[key]):
                k = seg.start + round(marks[key] / dt)
                ax.plot(marks[key], yy[k], "o", ms=4.5, mfc="white", mec=color, mew=1.2,
                        zorder=5)  # fmt: skip
        if np.isfinite(marks["peak_s"]):
            k = seg.start + round(marks["peak_s"] / dt)
            if marks["peak_s"] <= z.window_s[1]:
                ax.plot(marks["peak_s"], yy[k], "D", ms=4, color=color, zorder=5)
            else:  # a late peak (a wobble within the band): marked at the edge, with its time
                ax.plot(z.window_s[1], yy[k], ">", ms=5, color=color, zorder=5, clip_on=False)
                notes.append(f"{who}'s peak: at {marks['peak_s']:.3g} s (>)")
        if np.isfinite(marks["settled_s"]):
            ax.axvline(marks["settled_s"], color=color, ls=":", lw=1.1)
            if marks["settled_s"] > z.window_s[1]:
                ax.plot(z.window_s[1], final, ">", ms=5, color=color, zorder=5, clip_on=False)
                notes.append(f"{who} settles for good at {marks['settled_s']:.3g} s (>)")
    window = np.concatenate([ref[i0:i1], y_model[i0:i1][np.isfinite(y_model[i0:i1])],
                             y[finite, i0:i1].ravel(),
                             [final - z.band_deg, final + z.band_deg]])  # fmt: skip
    note = _ylim(ax, float(window.min()), float(window.max()), min(seg.initial_deg, final),
                 max(seg.initial_deg, final))  # fmt: skip
    ax.set_xlim(*z.window_s)
    notes += [note] if note else []
    # the metrics box sits on the side the response has left: above a grip, below an un-grip
    box = "\n".join([metrics_table(z), *notes])
    ax.text(0.985, 0.97 if move < 0 else 0.03, box, transform=ax.transAxes,
            ha="right", va="top" if move < 0 else "bottom", fontsize=7, family="monospace",
            multialignment="left",
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7", "alpha": 0.92},
            zorder=6)  # fmt: skip
    when = (f"at t = {t[seg.start]:g} s" if z.arrive_s == 0 else
            f"ramp from t = {t[seg.start]:.3g} s to {t[seg.start] + z.arrive_s:.3g} s")  # fmt: skip
    ax.set_title(f"{letter}: {seg.kind} {seg.initial_deg:g} → {final:g} deg {when}", fontsize=9)
    ax.set_ylabel("jaw angle (deg)", fontsize=8)
    ax.grid(alpha=0.3)
    ax.tick_params(labelsize=8, labelbottom=False)

    ok = finite
    if ok.any():
        lo, hi = _nan_range(u[ok, i0:i1])
        axu.fill_between(tz, lo, hi, color=_ACTUAL, alpha=0.3, lw=0)
    if finite[med]:
        axu.plot(tz, u[med, i0:i1], color=_ACTUAL, lw=1.0)
    um = u_model[i0:i1]
    axu.plot(tz, um, color=_MODEL, lw=1.0)
    _servo_range(axu, np.concatenate([u[ok, i0:i1].ravel(), um[np.isfinite(um)]]))
    lo_s, hi_s = SERVO_RANGE_DEG
    beyond = np.where(np.isfinite(um), np.maximum(um - hi_s, lo_s - um), -np.inf)
    if beyond.size and beyond.max() > 0:  # the model's spike: what the servo cannot do
        k = int(np.argmax(beyond))
        high = um[k] > hi_s
        axu.plot(tz[k], um[k], "v" if high else "^", ms=5, color=_MODEL, zorder=5)
        axu.text(0.985, 0.94 if high else 0.06, f"the model's command peaks at {um[k]:.0f} deg",
                 transform=axu.transAxes, ha="right", va="top" if high else "bottom",
                 fontsize=7, color=_MODEL)  # fmt: skip
    axu.set_xlabel("time from the move (s)", fontsize=8)
    axu.set_ylabel("command (deg)", fontsize=8)
    axu.grid(alpha=0.3)
    axu.tick_params(labelsize=8)


def response_plot(
    evaluation: Any,
    title: str,
    path: str | os.PathLike[str],
    settling_band_deg: float = 0.0,
    *,
    model_settling_band_deg: float = 0.0,
    signal: str = "true",
) -> Path:
    """The response as a control engineer reads it, written to ``path`` (PNG).

    * **Overview** (the whole run): the reference, the model's response (the ideal transfer
      function) and the actual model's over the held-out seeds as a band (min to max) with the
      median seed (by IAE) drawn; the zoom windows shaded and lettered.
    * **A zoom on each move** (every move of a profile of up to :data:`MAX_ZOOMS`, else the
      first grip and un-grip; from 50 ms before the move until 1.3 times the later settling
      time of the model and the median seed): the same curves, the settling bands the metrics
      use (``max(2 % of the move, the objective's floor)``: shaded for the actual model, dotted
      for the model when it differs), the 10 % and 90 % levels, and on the model and on the
      median seed the 10 % / 90 % crossings (the rise), the peak (the overshoot) and the
      instant it settled for good. A box gives the move's overshoot, rise and settling time
      for the model and the actual model's mean (and range) over the seeds, as
      :func:`step_zooms` computes them with the project's metrics.
    * **The command** under each zoom and over the whole run: unclipped (the model's PID has no
      limits; its spikes are what the servo cannot do), the actual model's band over the seeds
      and its median seed, the servo's 0-180 deg range as dotted lines; the axis always holds
      every command drawn.

    Parameters
    ----------
    evaluation : tuners.evaluation.Evaluation
        What to draw (trajectories and metrics).
    title : str
        Figure title.
    path : path
        PNG file to write.
    settling_band_deg : float
        The objective's settling-band floor on the actual model's preset (deg).
    model_settling_band_deg : float
        The same on the ``ideal`` preset the model is scored on (deg; 0 for the shipped one,
        so the model's band is 2 % of the move).
    signal : {"true", "measured"}
        The objective's signal: the jaw angle drawn and scored.
    """
    fig = response_figure(evaluation, title, settling_band_deg,
                          model_settling_band_deg=model_settling_band_deg,
                          signal=signal)  # fmt: skip
    return save_figure(fig, path, dpi=100)


def budget_plot(
    curves: Mapping[str, Sequence[tuple[int, float]]],
    title: str,
    path: str | os.PathLike[str],
) -> Path:
    """Best cost so far against simulated episodes used, one line per tuner.

    Parameters
    ----------
    curves : mapping of label to [(episodes, best cost), ...]
        Monotone curves.
    """
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, pts in curves.items():
        if not pts:
            continue
        x, y = zip(*pts, strict=True)
        ax.step(x, y, where="post", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    # plain numbers at 1, 1.2, 1.5, 2, 3, 5, 7 per decade: the final costs sit within a decade
    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 1.2, 1.5, 2.0, 3.0, 5.0, 7.0)))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("simulated episodes (20 s runs on the actual model)")
    ax.set_ylabel("best feasible cost so far (tuning seeds)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return save_figure(fig, path, bbox_inches="tight")


def learning_curve_plot(
    curves: Sequence[tuple[Sequence[float], Sequence[float]]],
    path: str | os.PathLike[str],
    title: str,
    xlabel: str,
    ylabel: str,
    lines: Mapping[str, float] | None = None,
    labels: Sequence[str] | None = None,
) -> Path:
    """Learning curves over training seeds: each seed thin, their mean bold with the band
    between the best and the worst seed, and reference levels as dashed lines.

    Parameters
    ----------
    curves : sequence of (x, y)
        One curve per seed, on the same ``x`` (NaN where undefined, e.g. infeasible gains).
    lines : mapping of label to level, optional
        Horizontal references (the base PID, the search's best).
    """
    fig, ax = plt.subplots(figsize=(7, 4.2))
    x = np.asarray(curves[0][0], dtype=float)
    keep = [i for i, c in enumerate(curves) if len(c[1]) == len(x)]
    ys = np.array([np.asarray(curves[i][1], dtype=float) for i in keep])
    for j, (i, y) in enumerate(zip(keep, ys, strict=True)):  # each seed its colour, not the mean's
        ax.plot(x, y, lw=0.8, alpha=0.7, color=f"C{j % 9 + 1}",
                label=(labels[i] if labels else ("seeds" if j == 0 else None)))  # fmt: skip
    if len(ys) > 1:
        with np.errstate(all="ignore"):
            lo, hi, mean = np.nanmin(ys, axis=0), np.nanmax(ys, axis=0), np.nanmean(ys, axis=0)
        ax.fill_between(x, lo, hi, alpha=0.15, color="tab:blue", label="best to worst seed")
        ax.plot(x, mean, lw=2, color="tab:blue", label=f"mean of {len(ys)} seeds")
    for i, (label, level) in enumerate((lines or {}).items()):
        ax.axhline(level, ls="--", lw=1.2, color=("k", "tab:red", "tab:green")[i % 3], label=label)
    finite = ys[np.isfinite(ys)]
    if finite.size:
        top = np.percentile(finite, 95)
        levels = [v for v in (lines or {}).values() if np.isfinite(v)]
        bottom = min([finite.min(), *levels])
        ax.set_ylim(bottom - 0.05 * (top - bottom), max([top, *levels]) + 0.1 * (top - bottom))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    # beside the axes: the curves fill them, and a legend inside hid a part of them
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return save_figure(fig, path, bbox_inches="tight")


_KIND_STYLE = {
    "reference": ("k", "s"),
    "manual": ("tab:gray", "v"),
    "baseline": ("tab:blue", "o"),
    "search": ("tab:red", "^"),
    "controller": ("tab:green", "*"),
}


def pareto_plot(data: Mapping[str, Any], path: str | os.PathLike[str]) -> Path:
    """Tracking against robustness, one panel per feasible plant: every PID row's actual-model
    IAE against its Ms with the servo's hold, the MIGO front (the best IAE each Ms allows a PI),
    the Ms limit (the feasible side shaded), and as horizontal lines the oracle's IAE and the
    limit's. ``command = reference`` (open loop, S = 1) sits at Ms = 1. Rows far worse than the
    best are drawn as arrows at the top edge with their IAE."""
    plants = [p for p, d in data["plants"].items() if d.get("feasible")]
    n = max(1, len(plants))
    fig, axes = plt.subplots(1, n, figsize=(5.4 * n, 5.0), squeeze=False)
    for ax, plant in zip(axes[0], plants, strict=False):
        pdata = data["plants"][plant]
        refs = pdata.get("references", {})
        points = []
        ms_max = None
        rows = dict(pdata.get("rows", {}))
        if "command=reference" in refs:
            rows["command=reference"] = refs["command=reference"]
        for name, row in rows.items():
            rb = row["robustness"]
            ms = rb.get("ms")
            iae = row["metrics"]["actual"]["mean"]["iae"]
            if ms is None or iae is None or not np.isfinite(iae):
                continue
            ms_max = (rb.get("constraints") or {}).get("ms_max", ms_max)
            points.append((name, row["kind"], min(ms, 4.0), iae))
        if not points:
            continue
        best = min(p[3] for p in points)
        top = 2.6 * best
        front = (data.get("pareto_fronts") or {}).get(plant) or []
        if front:
            ax.plot([f["ms"] for f in front], [min(f["iae"], top) for f in front], "-",
                    color="0.55", lw=1.5, label="MIGO front (max I per Ms)", zorder=1)  # fmt: skip
        floor = best
        for name, style in (("oracle", ":"), ("limit", "--")):
            ref = refs.get(name)
            if ref is None:
                continue
            level = ref["iae"] if name == "limit" else ref["metrics"]["actual"]["mean"]["iae"]
            floor = min(floor, level)
            ax.axhline(level, color="tab:green" if name == "oracle" else "k", ls=style, lw=1,
                       label="oracle (MPC, actual model)" if name == "oracle"
                       else "limit (any command, ideal model)")  # fmt: skip
        if ms_max:
            ax.axvspan(0.9, ms_max, color="tab:green", alpha=0.06, lw=0)
            ax.axvline(ms_max, color="tab:red", ls=":", lw=1, label=f"Ms limit {ms_max:g}")
        seen = set()
        for name, kind, ms, iae in points:
            color, marker = _KIND_STYLE.get(kind, ("tab:olive", "x"))
            label = kind if kind not in seen else None
            seen.add(kind)
            short = name.replace("classical-", "").replace("manual-", "")
            if iae > top:  # off the chart: an arrow at the top edge, with its IAE
                ax.scatter([ms], [top], c=color, marker="^", s=30, label=label, zorder=3)
                ax.annotate(f"{short} ({iae:.0f})", (ms, top), fontsize=6, xytext=(3, -9),
                            textcoords="offset points", color="0.3")  # fmt: skip
                continue
            ax.scatter([ms], [iae], c=color, marker=marker, s=40, label=label, zorder=3)
            ax.annotate(short, (ms, iae), fontsize=6, xytext=(3, 2), textcoords="offset points")
        ax.set_xlim(0.9, 4.15)
        ax.set_ylim(0.9 * floor, top * 1.04)
        ax.set_xlabel("Ms with the 20 ms servo hold (capped at 4; shaded: feasible)")
        ax.set_ylabel("IAE on the actual model (deg s)")
        ax.set_title(f"{plant}: tracking against robustness", fontsize=10)
        ax.grid(alpha=0.3)
    handles: dict[str, Any] = {}
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=len(handles),
               fontsize=8, frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return save_figure(fig, path, bbox_inches="tight")


def grasp_plot(
    runs: Sequence[tuple[str, Any]],
    path: str | os.PathLike[str],
    title: str,
    *,
    mode_suffix: str | None = None,
) -> Path:
    """The grasp-and-hold scenario: the true jaw angle (top), the fingertip force (middle) and
    the servo's heat relative to its thermal trip (bottom) against time from the close command,
    one line per controller (the mean over its runs), the object and the close command, the hold
    window shaded, the required force and the stall force, the trip level, and an x where the
    overload criterion first trips (earliest run).

    Parameters
    ----------
    runs : sequence of (label, GraspRun)
        :class:`gripper_env.evaluation.grasp.GraspRun` of each controller, one scenario.
    mode_suffix : str, optional
        Labels ending in it are a controller with the PID's grasp mode: drawn solid in the
        colour of the label without it (drawn dashed, the plain PID).
    """
    from gripper_env.evaluation.grasp import thermal_state

    if not runs:
        raise ValueError("no grasp runs to draw")
    scenario = runs[0][1].scenario
    fig, (ax_jaw, ax_force, ax_heat) = plt.subplots(
        3, 1, figsize=(9.5, 8.2), sharex=True, height_ratios=(1.0, 1.2, 0.8)
    )
    lo, hi = scenario.hold_window_s
    t = runs[0][1].t_s
    bases: list[str] = []
    for label, _ in runs:
        base = label.removesuffix(mode_suffix) if mode_suffix else label
        if base not in bases:
            bases.append(base)
    styles = ("-", "--", "-.", ":")
    for label, run in runs:
        mode = bool(mode_suffix) and label.endswith(mode_suffix or "")
        base = label.removesuffix(mode_suffix) if mode and mode_suffix else label
        j = bases.index(base)
        color = f"C{j % 10}"
        if mode_suffix:
            has_mode = any(lab == base + mode_suffix for lab, _ in runs)
            ls, lw = ("-", 1.6) if mode or not has_mode else ("--", 1.0)
        else:
            ls, lw = styles[(j // 10 + j) % len(styles)], 1.3
        after = run.t_s >= -1e-9
        with np.errstate(all="ignore"):
            jaw = np.nanmean(run.jaw_deg, axis=0)
            force = np.nanmean(run.force_n, axis=0)
            heat = np.mean([thermal_state(run.t_s[after], c[after]) for c in
                            run.current_fraction], axis=0)  # fmt: skip
        name = "_" if mode_suffix else label  # with pairs, the legend has a colour per base
        ax_jaw.plot(run.t_s, jaw, color=color, ls=ls, lw=lw, label=name)
        ax_force.plot(run.t_s, force, color=color, ls=ls, lw=lw, label=name)
        ax_heat.plot(run.t_s[after], 100 * heat, color=color, ls=ls, lw=lw, label=name)
        trips = [x for x in run.overload_at_s if x is not None]
        if trips:
            k = min(int(np.searchsorted(run.t_s, min(trips))), len(run.t_s) - 1)
            ax_force.plot([min(trips)], [force[k]], "x", color=color, ms=9, mew=2)
    for ax in (ax_jaw, ax_force, ax_heat):
        ax.axvspan(lo, hi, color="tab:green", alpha=0.08, lw=0)
        ax.axvline(0.0, color="0.5", lw=0.8)
        ax.grid(alpha=0.3)
    if scenario.object_deg is not None:
        ax_jaw.axhline(scenario.object_deg, color="k", lw=1.0, ls="--",
                       label=f"object ({scenario.object_deg:g} deg)")  # fmt: skip
    ax_jaw.axhline(scenario.close_command_deg, color="0.4", lw=0.8, ls=":",
                   label=f"close command ({scenario.close_command_deg:g} deg)")  # fmt: skip
    ax_jaw.set_ylabel("true jaw angle (deg)")
    ax_jaw.set_title(title, fontsize=10)
    stall = runs[0][1].stall_force_n
    ax_force.axhline(scenario.required_force_n, color="tab:red", lw=1.2, ls="--",
                     label=f"required {scenario.required_force_n:g} N")  # fmt: skip
    ax_force.axhline(stall, color="0.3", lw=0.8, ls=":", label=f"stall force {stall:.3g} N")
    ax_force.plot([], [], "x", color="0.3", ms=8, mew=2, label="overload trips (earliest run)")
    ax_force.plot([], [], color="tab:green", alpha=0.3, lw=6, label="hold window")
    ax_force.set_ylim(-0.05 * stall, 1.12 * stall)
    ax_force.set_ylabel("fingertip force (N)")
    ax_heat.axhline(100.0, color="tab:red", lw=1.2, ls="--", label="thermal trip")
    ax_heat.set_ylim(-5.0, 115.0)
    ax_heat.set_ylabel("servo heat (% of trip)")
    ax_heat.set_xlabel("time from the close command (s); lines: mean over the runs")
    ax_heat.set_xlim(max(float(t[0]), -0.2), float(t[-1]))
    handles: dict[str, Any] = {}
    if mode_suffix:
        for j, base in enumerate(bases):
            handles[base] = Line2D([], [], color=f"C{j % 10}", lw=1.6)
    for ax in (ax_jaw, ax_force, ax_heat):
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    if mode_suffix:
        handles["plain PID"] = Line2D([], [], color="0.3", ls="--", lw=1.0)
        handles[f"with{mode_suffix.replace(' + ', ' the ')}"] = Line2D([], [], color="0.3", lw=1.6)
    fig.legend(handles.values(), handles.keys(), loc="upper left", bbox_to_anchor=(0.99, 0.95),
               fontsize=8, frameon=False)  # fmt: skip
    fig.tight_layout()
    return save_figure(fig, path, bbox_inches="tight")

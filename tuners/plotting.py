"""Figures: a controller's response (like the paper's Figure 11) and the benchmark's plots.

matplotlib with the Agg backend (no display needed); every figure is written atomically
(:func:`gripper_env.io.files.save_figure`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np

from gripper_env.io.files import save_figure

__all__ = ["budget_plot", "learning_curve_plot", "pareto_plot", "response_plot"]


def response_plot(
    evaluation: Any,
    title: str,
    path: str | os.PathLike[str],
    settling_band_deg: float = 0.0,
) -> Path:
    """The response as a control engineer reads it.

    * **Overview** (20 s): the reference, the ideal model's response, and the actual model's
      over the held-out seeds as a band (min to max) with the median seed drawn.
    * **Zoom on each move** (the first grip and un-grip, from 50 ms before the step to 0.6 s
      after): the same curves, every seed thin, the settling band (``max(2 %, band)`` of the
      move, the objective's) shaded, and the actual model's mean overshoot, rise (10-90 %) and
      settling time annotated.
    * **Command**: the controller's output for the ideal model and the median seed, unclipped
      (its spikes are where it saturates), with the servo's range marked.

    Parameters
    ----------
    evaluation : tuners.evaluation.Evaluation
        What to draw (trajectories and metrics).
    title : str
        Figure title.
    path : path
        PNG file to write.
    settling_band_deg : float
        The objective's settling-band floor (deg).
    """
    ideal, actual = evaluation.ideal_trajectory, evaluation.actual_trajectory
    t = ideal.t
    y = actual.y_true
    finite = np.isfinite(y).all(axis=1)
    iae = np.array([np.sum(np.abs(row - ideal.r[0])) if ok else np.inf
                    for row, ok in zip(y, finite, strict=True)])  # fmt: skip
    median = int(np.argsort(iae)[len(iae) // 2])
    fig = plt.figure(figsize=(10, 8.6))
    grid = fig.add_gridspec(3, 2, height_ratios=[2.2, 2.2, 1.3], hspace=0.42, wspace=0.2)
    ax = fig.add_subplot(grid[0, :])
    segments = list(ideal.reference.segments)
    ax.plot(t, ideal.r[0], color="k", lw=1.1, ls="--", label="reference")
    if finite.any():
        ax.fill_between(t, np.nanmin(y[finite], axis=0), np.nanmax(y[finite], axis=0),
                        color="tab:orange", alpha=0.25, lw=0,
                        label=f"actual model, {int(finite.sum())} seeds (min-max)")  # fmt: skip
    ax.plot(t, y[median], color="tab:orange", lw=1.0,
            label=f"actual, median seed ({evaluation.seeds[median]})")  # fmt: skip
    ax.plot(t, ideal.y_true[0], color="tab:blue", lw=1.2, label="model (ideal TF)")
    for seg in segments[:2]:
        ax.axvspan(t[seg.start] - 0.05, t[seg.start] + 0.6, color="0.85", alpha=0.5, lw=0)
    ax.set_ylabel("jaw angle (deg)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="best", fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    mean = evaluation.actual.get("mean", {}) if isinstance(evaluation.actual, dict) else {}
    firsts = {seg.kind: seg for seg in reversed(segments)}
    for col, kind in enumerate(("grip", "ungrip")):
        seg = firsts.get(kind)
        axz = fig.add_subplot(grid[1, col])
        if seg is None:
            axz.set_visible(False)
            continue
        _zoom(axz, t, ideal, y, finite, median, seg, settling_band_deg, mean.get(kind) or {})
    axu = fig.add_subplot(grid[2, :], sharex=ax)
    axu.plot(t, ideal.u[0], color="tab:blue", lw=0.8, label="command, model")
    axu.plot(t, actual.u[median], color="tab:orange", lw=0.6, alpha=0.9,
             label="command, actual (median seed)")  # fmt: skip
    for edge in (0.0, 180.0):
        axu.axhline(edge, color="tab:red", lw=0.6, ls=":")
    axu.set_xlabel("time (s)")
    axu.set_ylabel("command (deg)")
    axu.grid(alpha=0.3)
    axu.legend(loc="best", fontsize=7, title="unclipped; dotted: the servo's range",
               title_fontsize=7)  # fmt: skip
    return save_figure(fig, path, bbox_inches="tight")


def _zoom(
    ax: Any, t: np.ndarray, ideal: Any, y: np.ndarray, finite: np.ndarray, median: int, seg: Any,
    band_floor: float, metrics: dict[str, Any],
) -> None:  # fmt: skip
    """One move, zoomed: every seed, the settling band, the metrics annotated."""
    dt = float(t[1] - t[0])
    i0 = max(0, seg.start - round(0.05 / dt))
    i1 = min(len(t), seg.start + round(0.6 / dt))
    tz = t[i0:i1] - t[seg.start]
    move = seg.final_deg - seg.initial_deg
    band = max(0.02 * abs(move), band_floor)
    ax.axhspan(seg.final_deg - band, seg.final_deg + band, color="tab:green", alpha=0.12,
               lw=0, label=f"settling band +/-{band:.2g} deg")  # fmt: skip
    ax.plot(tz, ideal.r[0, i0:i1], color="k", lw=1.0, ls="--")
    for b in np.flatnonzero(finite):
        ax.plot(tz, y[b, i0:i1], color="tab:orange", lw=0.5, alpha=0.45)
    ax.plot(tz, y[median, i0:i1], color="tab:orange", lw=1.2, label="actual seeds (median bold)")
    ax.plot(tz, ideal.y_true[0, i0:i1], color="tab:blue", lw=1.2, label="model (ideal TF)")
    words = []
    for key, label, unit, scale in (("overshoot_pct", "overshoot", "%", 1.0),
                                    ("rise_time_s", "rise", "ms", 1e3),
                                    ("settling_time_s", "settling", "ms", 1e3)):  # fmt: skip
        value = metrics.get(key)
        if value is None or not np.isfinite(value):
            words.append(f"{label}: never" if key != "overshoot_pct" else f"{label}: -")
            continue
        words.append(f"{label} {value * scale:.3g} {unit}")
        if key == "settling_time_s":  # settled for good from here (time from the step)
            ax.axvline(value, color="tab:green", lw=0.8, ls=":")
    text = "actual, mean of seeds\n(dotted: settled):\n" + "\n".join(words)
    ax.text(0.98, 0.5, text, transform=ax.transAxes,
            ha="right", va="center", fontsize=7,
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7", "alpha": 0.9})  # fmt: skip
    ax.set_title(f"{seg.kind}: {seg.initial_deg:g} -> {seg.final_deg:g} deg", fontsize=9)
    ax.set_xlabel("time from the step (s)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left" if move > 0 else "upper left", fontsize=6)


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
    ys = np.array([np.asarray(c[1], dtype=float) for c in curves if len(c[1]) == len(x)])
    for i, y in enumerate(ys):
        ax.plot(x, y, lw=0.7, alpha=0.5,
                label=(labels[i] if labels else ("seeds" if i == 0 else None)))  # fmt: skip
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
    ax.legend(fontsize=8)
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

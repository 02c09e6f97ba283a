"""Evaluate one set of gains the way every tuner and the benchmark report it.

The same controller (gains and :class:`~gripper_env.pid.PIDOptions`) runs on two models over one
reference profile:

* ``ideal``: the identified transfer function alone (the paper's "model"), one deterministic run;
* ``actual``: the actual-gripper preset (default ``actual``), one run per held-out disturbance
  seed (friction and noise drawn from the preset's ``randomize`` ranges), summarised as mean,
  sample standard deviation and the 95 % confidence interval of the mean (Student t).

Metrics use the project's JSON keys (:meth:`gripper_env.metrics.Metrics.as_dict`) plus ``cost``,
the shared objective (:mod:`gripper_env.objective`). ``sim_to_real_gap`` is ``actual mean - ideal``
for every numeric metric.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from gripper_env.disturbances import load_disturbance
from gripper_env.metrics import compute_metrics
from gripper_env.objective import Objective, load_objective
from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.plants import Plant, load_plant
from gripper_env.references import Reference, load_reference
from gripper_env.simulation import Trajectory, simulate

__all__ = ["Evaluation", "evaluate", "metric_rows", "summarize_runs"]


@dataclass
class Evaluation:
    """Metrics of one controller on the ``ideal`` and ``actual`` models.

    Attributes
    ----------
    ideal : dict
        Metrics of the one ideal run (JSON keys, plus ``cost``).
    actual : dict
        ``mean``, ``std``, ``ci95_low``, ``ci95_high`` (each a metrics dict), ``n_seeds``,
        ``stable_fraction``.
    actual_runs : list of dict
        Metrics of each seed's run.
    sim_to_real_gap : dict
        ``actual mean - ideal`` per numeric metric.
    seeds : list of int
        The held-out disturbance seeds.
    ideal_trajectory, actual_trajectory : Trajectory
        The ideal run and the actual runs (one per seed), for plots and CSV.
    """

    ideal: dict[str, Any]
    actual: dict[str, Any]
    actual_runs: list[dict[str, Any]]
    sim_to_real_gap: dict[str, Any]
    seeds: list[int]
    ideal_trajectory: Trajectory
    actual_trajectory: Trajectory


def _with_cost(metrics, objective: Objective, duration_s: float) -> list[dict[str, Any]]:
    costs = objective.cost(metrics, duration_s)
    rows = []
    for i in range(len(metrics)):
        row = metrics.as_dict(i)
        row["cost"] = float(costs[i])
        rows.append(row)
    return rows


def _map(fn, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Apply ``fn(list of values)`` key by key over equally shaped metric dicts."""
    out: dict[str, Any] = {}
    for key, value in rows[0].items():
        if isinstance(value, dict):
            out[key] = _map(fn, [r[key] for r in rows])
        elif isinstance(value, bool):
            out[key] = all(r[key] for r in rows)
        else:
            out[key] = fn(np.array([r[key] for r in rows], dtype=float))
    return out


def summarize_runs(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean, std (ddof=1), 95 % CI of the mean over runs; ``inf`` if any run has ``inf``."""
    n = len(rows)
    t = float(stats.t.ppf(0.975, n - 1)) if n > 1 else math.inf

    def mean(v: np.ndarray) -> float:
        return float(v.mean()) if np.all(np.isfinite(v)) else math.inf

    def std(v: np.ndarray) -> float:
        if not np.all(np.isfinite(v)):
            return math.inf
        return float(v.std(ddof=1)) if n > 1 else 0.0

    def half(v: np.ndarray) -> float:
        s = std(v)
        return t * s / math.sqrt(n) if math.isfinite(s) and s > 0 else (0.0 if s == 0 else s)

    return {
        "mean": _map(mean, rows),
        "std": _map(std, rows),
        "ci95_low": _map(lambda v: mean(v) - half(v), rows),
        "ci95_high": _map(lambda v: mean(v) + half(v), rows),
        "n_seeds": n,
        "stable_fraction": float(np.mean([r["stable"] for r in rows])),
    }


def _gap(actual: dict[str, Any], ideal: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in ideal.items():
        if isinstance(value, dict):
            out[key] = _gap(actual[key], value)
        elif not isinstance(value, bool):
            a, b = actual[key], value
            out[key] = a - b if math.isfinite(a) and math.isfinite(b) else math.inf
    return out


def evaluate(
    plant: str | Plant,
    gains: PIDGains,
    options: PIDOptions,
    *,
    profile: str | Reference = "step",
    disturbance: str = "actual",
    seeds: np.ndarray | list[int] = (100000,),
    randomize: bool = True,
    signal: str = "measured",
    objective: Objective | None = None,
    ideal_options: PIDOptions | None = None,
) -> Evaluation:
    """Run the controller on the ideal model once and on the actual model once per seed.

    Parameters
    ----------
    plant : str or Plant
        Plant name or object.
    gains : PIDGains
        The gains.
    options : PIDOptions
        Limits, anti-windup, derivative input, sign convention.
    profile : str or Reference
        Reference profile (``"step"``, ``"slope60"``, ... or a CSV path).
    disturbance : str
        Actual-gripper preset (name or YAML path).
    seeds : array of int
        Held-out disturbance seeds.
    randomize : bool
        Draw each seed's disturbance parameters from the preset's ranges.
    signal : {"measured", "true"}
        Which angle the metrics score.
    objective : Objective, optional
        Default: ``configs/objective.yaml``.
    ideal_options : PIDOptions, optional
        PID options on the ideal model (default ``options``); the paper's model had no limits.
    """
    p = load_plant(plant)
    ref = load_reference(profile, p.dt_s)
    dist = load_disturbance(disturbance)
    obj = objective or load_objective()
    seed_arr = np.asarray(seeds, dtype=np.int64)
    row = gains.as_array()[None, :]
    ideal_traj = simulate(
        p, ref, gains=row, disturbance="ideal", pid_options=ideal_options or options
    )
    actual_traj = simulate(
        p,
        ref,
        gains=np.repeat(row, len(seed_arr), axis=0),
        disturbance=dist,
        seeds=seed_arr,
        randomize=randomize,
        pid_options=options,
    )
    ideal = _with_cost(compute_metrics(ideal_traj, signal), obj, ref.duration_s)[0]
    runs = _with_cost(compute_metrics(actual_traj, signal), obj, ref.duration_s)
    summary = summarize_runs(runs)
    return Evaluation(
        ideal=ideal,
        actual=summary,
        actual_runs=runs,
        sim_to_real_gap=_gap(summary["mean"], ideal),
        seeds=[int(s) for s in seed_arr],
        ideal_trajectory=ideal_traj,
        actual_trajectory=actual_traj,
    )


#: Rows of the printed metrics table: (label, path into a metrics dict).
TABLE_ROWS = (
    ("grip overshoot %", ("grip", "overshoot_pct")),
    ("un-grip overshoot %", ("ungrip", "overshoot_pct")),
    ("grip settling s", ("grip", "settling_time_s")),
    ("un-grip settling s", ("ungrip", "settling_time_s")),
    ("grip rise s", ("grip", "rise_time_s")),
    ("SD deg", ("sd_deg",)),
    ("SD gap deg", ("sd_gap_deg",)),
    ("IAE deg*s", ("iae",)),
    ("control effort deg", ("control_effort",)),
    ("cost", ("cost",)),
)


def _get(d: dict[str, Any], path: tuple[str, ...]) -> Any:
    for k in path:
        d = d[k]
    return d


def metric_rows(evaluation: Evaluation) -> list[tuple[str, float, float, float]]:
    """``(label, ideal, actual mean, actual 95 % CI half-width)`` per table row."""
    rows = []
    for label, path in TABLE_ROWS:
        mean = _get(evaluation.actual["mean"], path)
        high = _get(evaluation.actual["ci95_high"], path)
        half = high - mean if math.isfinite(mean) and math.isfinite(high) else math.inf
        rows.append((label, _get(evaluation.ideal, path), mean, half))
    return rows

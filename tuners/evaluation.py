"""Evaluate one set of gains the way every tuner and the benchmark report it.

The same controller (gains and :class:`~gripper_env.model.pid.PIDOptions`) is scored through the one
scoring path (:mod:`gripper_env.evaluation.scoring`):

* ``ideal``: the identified transfer function alone (the paper's "model"), one deterministic run;
* ``actual``: the actual-gripper preset (default ``actual``), one run per held-out disturbance
  seed (friction, noise and stop positions drawn from the preset's ``randomize`` ranges),
  summarised as mean, sample standard deviation and the 95 % confidence interval of the mean
  (Student t);
* ``robustness``: stability, gain and phase margins, ``Ms`` and ``Mt`` of the loop as it runs
  (PID at 1 ms, the servo command held for the preset's refresh period) and of the 1 ms loop
  alone, and whether the gains meet the objective's constraints;
* ``cross_model``: the same gains on the other identifications of the gripper (the paper's four
  plants are four fits of one gripper): stability, margins and actual-model overshoot and IAE on
  each, and the worst case;
* ``admission``: the admission rule (:mod:`gripper_env.evaluation.admission`) on the held-out
  runs: robustness with the hold, every run settled, no stall, the jaw inside the nearest stops
  the preset can draw (the judge's verdict on this plant).

Metrics use the project's JSON keys (:meth:`gripper_env.evaluation.metrics.Metrics.as_dict`) plus
``cost``,
the shared objective (:mod:`gripper_env.evaluation.objective`), on the objective's signal (the true
jaw
angle by default). ``sim_to_real_gap`` is ``actual mean - ideal`` for every numeric metric.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from gripper_env.evaluation.metrics import Metrics
from gripper_env.evaluation.objective import Objective
from gripper_env.evaluation.scoring import GainScorer, Task, reachability
from gripper_env.evaluation.stability import stability_report
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference
from gripper_env.sim import Trajectory

__all__ = [
    "PAPER_PLANTS",
    "Evaluation",
    "cross_model",
    "evaluate",
    "metric_rows",
    "robustness_block",
    "summarize_runs",
    "with_cost",
    "worst_case",
]

#: The paper's four identifications of the one gripper (cross-model evaluation).
PAPER_PLANTS = ("test1", "test2", "test3", "test4")


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
    robustness : dict
        :func:`robustness_block` of the gains.
    cross_model : dict
        :func:`cross_model` of the gains (empty if not asked for).
    admission : dict
        The admission rule on the held-out runs
        (:meth:`gripper_env.evaluation.admission.Admission.row`).
    """

    ideal: dict[str, Any]
    actual: dict[str, Any]
    actual_runs: list[dict[str, Any]]
    sim_to_real_gap: dict[str, Any]
    seeds: list[int]
    ideal_trajectory: Trajectory
    actual_trajectory: Trajectory
    robustness: dict[str, Any] = field(default_factory=dict)
    cross_model: dict[str, Any] = field(default_factory=dict)
    admission: dict[str, Any] = field(default_factory=dict)


def with_cost(metrics: Metrics, costs: np.ndarray) -> list[dict[str, Any]]:
    """One dict per run: its metrics (JSON keys) and ``cost``."""
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
        if np.isnan(v).all():
            return math.nan
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


def robustness_block(
    plant: Plant,
    gains: PIDGains,
    sign: int,
    disturbance: Disturbance,
    objective: Objective,
) -> dict[str, Any]:
    """Stability and margins as the loop runs and at 1 ms, and the constraint verdict."""
    report = stability_report(plant, gains, sign, disturbance=disturbance)
    lim = objective.constraints
    block = report.as_dict()
    block["constraints"] = {"ms_max": lim.ms_max, "gm_min_db": lim.gm_min_db}
    block["meets_constraints"] = report.meets(lim.ms_max, lim.gm_min_db)
    return block


def cross_model(
    gains: PIDGains,
    sign: int,
    options: PIDOptions,
    *,
    plants: Sequence[Plant],
    reference: Reference,
    disturbance: Disturbance,
    seeds: Sequence[int] | np.ndarray,
    randomize: bool,
    objective: Objective,
) -> dict[str, Any]:
    """The gains on other identifications of the gripper: per plant and the worst case.

    Per plant: stability and margins as the loop runs, ``Ms``, and on the actual model the mean
    overshoot (worse of grip and un-grip), IAE and stall over the seeds. The worst case is over
    the plants on which the reference can be followed at all (:func:`reachability`: test1
    cannot follow the step profile within the servo's range, so it is listed, not counted).
    """
    per: dict[str, Any] = {}
    for plant in plants:
        task = Task.build(
            plant, reference, disturbance, seeds, randomize=randomize, options=options,
            objective=objective,
        )  # fmt: skip
        s = GainScorer(task).score(gains.as_array()[None, :])
        rb = robustness_block(plant, gains, sign, disturbance, objective)
        reach = reachability(plant, task.reference, disturbance)
        per[plant.name] = cross_model_entry(rb, s.metrics, reach.feasible)
        per[plant.name]["admission"] = s.admission.row(0)
    return worst_case(per)


def cross_model_entry(
    robustness: dict[str, Any], metrics: Metrics, profile_feasible: bool
) -> dict[str, Any]:
    """One plant's entry of :func:`cross_model`: the loop's margins (``robustness``, a
    :func:`robustness_block`) and the means over the runs on the actual model (``metrics``)."""
    m = metrics
    overshoot = np.maximum(m.grip["overshoot_pct"], m.ungrip["overshoot_pct"])
    return {
        "stable": robustness["stable"],
        "ms": robustness["ms"],
        "gain_margin_db": robustness["gain_margin_db"],
        "phase_margin_deg": robustness["phase_margin_deg"],
        "meets_constraints": robustness["meets_constraints"],
        "stable_runs": float(np.mean(m.stable)),
        "overshoot_pct": float(np.mean(overshoot)),
        "iae": float(np.mean(m.run["iae"])),
        "stall_s": float(np.mean(m.run["stall_s"])),
        "profile_feasible": profile_feasible,
    }


def worst_case(per: dict[str, Any]) -> dict[str, Any]:
    """:func:`cross_model`'s result from its per-plant entries: the worst case over the plants
    whose profile is feasible (also used for policies, :mod:`tuners.rl_controller`)."""
    counted = {k: v for k, v in per.items() if v["profile_feasible"]}
    if not counted:
        return {"plants": per, "worst": {}} if per else {}

    def worst(key: str, pick) -> Any:
        values = [v[key] for v in counted.values()]
        if key in ("ms", "gain_margin_db", "phase_margin_deg"):
            values = [math.inf if x is None else x for x in values]
        return pick(values)

    return {
        "plants": per,
        "worst": {
            "over": sorted(counted),
            "stable": all(v["stable"] and v["stable_runs"] == 1.0 for v in counted.values()),
            "ms": worst("ms", max),
            "gain_margin_db": worst("gain_margin_db", min),
            "phase_margin_deg": worst("phase_margin_deg", min),
            "overshoot_pct": worst("overshoot_pct", max),
            "iae": worst("iae", max),
            "stall_s": worst("stall_s", max),
            "meets_constraints": all(v["meets_constraints"] for v in counted.values()),
            "admitted": all(
                (v.get("admission") or {}).get("admitted", v["meets_constraints"])
                for v in counted.values()
            ),
        },
    }


def evaluate(
    plant: Plant,
    gains: PIDGains,
    options: PIDOptions,
    *,
    profile: Reference,
    disturbance: Disturbance,
    ideal: Disturbance,
    objective: Objective,
    seeds: Sequence[int] | np.ndarray = (100000,),
    randomize: bool = True,
    ideal_options: PIDOptions | None = None,
    cross_plants: Sequence[Plant] = (),
) -> Evaluation:
    """Score the controller on the ideal model once and on the actual model once per seed.

    Parameters
    ----------
    plant : Plant
        The plant.
    gains : PIDGains
        The gains.
    options : PIDOptions
        Limits, anti-windup, derivative input, sign convention.
    profile : Reference
        Reference profile.
    disturbance : Disturbance
        Actual-gripper preset.
    ideal : Disturbance
        The transfer function alone (the ``ideal`` preset).
    objective : Objective
        The cost and its constraints.
    seeds : array of int
        Held-out disturbance seeds.
    randomize : bool
        Draw each seed's disturbance parameters from the preset's ranges.
    ideal_options : PIDOptions, optional
        PID options on the ideal model (default ``options``); the paper's model had no limits.
    cross_plants : sequence of Plant
        Other identifications to score the same gains on (:func:`cross_model`).

    The commands load these once (:func:`tuners.cli.resolve`); nothing here reads a file.
    """
    p, ref, dist, obj = plant, profile, disturbance, objective
    seed_arr = np.asarray(seeds, dtype=np.int64)
    row = gains.as_array()[None, :]
    ideal_scores = GainScorer(
        Task.build(p, ref, ideal, [0], randomize=False, options=ideal_options or options,
                   objective=obj)
    ).score(row, keep_trajectory=True)  # fmt: skip
    actual = GainScorer(
        Task.build(p, ref, dist, seed_arr, randomize=randomize, options=options, objective=obj)
    ).score(row, keep_trajectory=True)
    assert ideal_scores.trajectory is not None and actual.trajectory is not None  # keep_trajectory
    ideal_row = with_cost(ideal_scores.metrics, ideal_scores.run_cost.ravel())[0]
    runs = with_cost(actual.metrics, actual.run_cost.ravel())
    summary = summarize_runs(runs)
    others = [other for other in cross_plants if other.name != p.name]
    return Evaluation(
        ideal=ideal_row,
        actual=summary,
        actual_runs=runs,
        sim_to_real_gap=_gap(summary["mean"], ideal_row),
        seeds=[int(s) for s in seed_arr],
        ideal_trajectory=ideal_scores.trajectory,
        actual_trajectory=actual.trajectory,
        robustness=robustness_block(p, gains, options.sign, dist, obj),
        admission=actual.admission.row(0),
        cross_model=cross_model(
            gains,
            options.sign,
            options,
            plants=others,
            reference=ref,
            disturbance=dist,
            seeds=seed_arr,
            randomize=randomize,
            objective=obj,
        ),
    )


#: Rows of the printed metrics table: (label, path into a metrics dict).
TABLE_ROWS = (
    ("IAE deg*s", ("iae",)),
    ("grip overshoot %", ("grip", "overshoot_pct")),
    ("un-grip overshoot %", ("ungrip", "overshoot_pct")),
    ("grip settling s", ("grip", "settling_time_s")),
    ("un-grip settling s", ("ungrip", "settling_time_s")),
    ("grip rise s", ("grip", "rise_time_s")),
    ("stall s", ("stall_s",)),
    ("saturation s", ("saturation_s",)),
    ("servo effort deg", ("servo_effort_deg",)),
    ("SD deg", ("sd_deg",)),
    ("SD gap deg", ("sd_gap_deg",)),
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

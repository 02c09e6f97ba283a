"""One policy on one task: its score on the task's scale and the benchmark's verdict.

:func:`judge_policy` runs a policy (with the environment arguments it brings, its
*interface*: a residual PID's gains, an action map) on the task's fixed evaluation set and
returns its row: the mean return and its spread, the normalised score with its evaluation
standard error and interval, the objective's cost, the constraint cost, the measured margins
and the admission verdict:

* ``margin`` tasks (the controllers): every evaluation episode ran to its end (no divergence)
  and the gain margin measured on each evaluation plant (:mod:`tuners.probe`) reaches the floor
  that ``Ms <= 1.6`` guarantees a linear loop (8.52 dB), the benchmark's rule for learned
  controllers;
* ``feasible`` (the tuning task): the gains chosen on every episode meet the objective's
  constraints (``Ms`` and the gain margin with the servo's hold);
* ``held`` (the grasp tasks): every episode held its object with the required force through the
  hold window without a trip.

:func:`best_pid` picks the best-PID row: among the committed gains files of the task's plants,
the best mean return on selection episodes of the training arguments (disjoint from the
evaluation set), among the sets the verdict admits on the training plants when any is.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tuners.rl.rollouts import (
    EpisodeStats,
    Policy,
    constant_policy,
    measured_margins,
    objective_costs,
    run_episodes,
)
from tuners.rl.scores import normalise, paired_se
from tuners.rl.suite import Task

__all__ = ["best_pid", "judge_policy", "pid_interface", "verdict"]


def _plants(kwargs: dict[str, Any]) -> list[str]:
    p = kwargs.get("plant", "test2")
    return [str(x) for x in p] if isinstance(p, list | tuple) else [str(p)]


def _episode_interval(
    returns: np.ndarray, r0: np.ndarray, r100: np.ndarray, reps: int = 5000
) -> tuple[float, float]:
    """95 % percentile interval of the score over the evaluation episodes (the policy's and the
    anchors' returns of each episode resampled together). Where the limit covers only the first
    ``n`` episodes, the two strata (those ``n``, the rest) are resampled separately, so the
    limit's mean keeps its ``n`` episodes and its pairing with the others'."""
    rng = np.random.default_rng(0)
    n, m = len(returns), len(r100)
    if m == n:
        idx = rng.integers(0, n, size=(reps, n))
        a, b, r = r0[idx].mean(axis=1), r100[idx].mean(axis=1), returns[idx].mean(axis=1)
    else:
        head = rng.integers(0, m, size=(reps, m))
        tail = m + rng.integers(0, n - m, size=(reps, n - m))
        a = (r0[head].sum(axis=1) + r0[tail].sum(axis=1)) / n
        r = (returns[head].sum(axis=1) + returns[tail].sum(axis=1)) / n
        b = r100[head].mean(axis=1)
    s = 100.0 * (r - a) / (b - a)
    lo, hi = np.percentile(s, [2.5, 97.5])
    return float(lo), float(hi)


def verdict(task: Task, row: dict[str, Any]) -> tuple[bool, str]:
    """``(admitted, why)`` for a judged row (module docstring)."""
    from gripper_env.envs.robust import margin_floor_db

    if task.verdict == "feasible":
        share = row["feasible_fraction"]
        return share == 1.0, f"gains feasible on {100 * share:.0f} % of the episodes"
    if task.verdict == "held":
        held, trip = row["held_fraction"], row["trip_fraction"]
        return held == 1.0, (f"held {100 * held:.0f} % of the objects, tripped on "
                             f"{100 * trip:.0f} %")  # fmt: skip
    floor = margin_floor_db()
    if row["completed_fraction"] < 1.0:
        return False, (f"diverged on {100 * (1 - row['completed_fraction']):.0f} % of the "
                       "episodes")  # fmt: skip
    margins = row.get("margins") or {}
    if not margins:
        return False, "margins not measured"
    worst = min(math.inf if m["gain_margin_db"] is None else m["gain_margin_db"]
                for m in margins.values())  # fmt: skip
    ok = worst >= floor
    text = "none up to 40 dB" if math.isinf(worst) else f"{worst:.1f} dB"
    return ok, f"measured gain margin {text} (worst plant) against the {floor:.2f} dB floor"


def judge_policy(
    task: Task,
    policy: Policy,
    anchors: dict[str, Any],
    interface: dict[str, Any] | None = None,
    *,
    margins: bool = True,
    seeds: list[int] | None = None,
) -> dict[str, Any]:
    """The row of ``policy`` on ``task`` (module docstring).

    Parameters
    ----------
    task : Task
    policy : callable
        ``obs (B, n_obs) -> actions (B, n_actions)``.
    anchors : dict
        The task's per-episode anchor returns, ``{"trivial": [...], "limit": [...]}`` (the
        reference scores' record).
    interface : dict, optional
        The environment arguments the agent brings (:attr:`Task.interface`).
    margins : bool
        Measure the margins (the ``margin`` verdict needs them).
    seeds : list of int, optional
        The held-out seeds of the objective's cost (default the evaluation settings').
    """
    kwargs = task.kwargs_with(interface)
    stats = run_episodes(task.env_id, kwargs, policy, task.eval_seeds,
                         grasp=task.family == "grasp")  # fmt: skip
    r0, r100 = np.asarray(anchors["trivial"]), np.asarray(anchors["limit"])
    if len(r0) != len(stats.returns) or len(r100) != len(task.limit_seeds):
        raise ValueError(
            f"task {task.name}: the anchors hold {len(r0)} episodes (the limit {len(r100)}), the "
            f"task {task.episodes} (the limit {len(task.limit_seeds)}); regenerate them (python "
            "-m tuners.rl.reference_scores)"
        )
    row = _returns_row(task, stats, r0, r100)
    if task.family == "tracking":
        held_out = seeds if seeds is not None else _held_out_seeds()
        row["objective_cost"] = objective_costs(policy, task.env_id, kwargs, _plants(kwargs),
                                                held_out)  # fmt: skip
        if margins:
            row["margins"] = measured_margins(policy, task.env_id, kwargs, _plants(kwargs))
    admitted, why = verdict(task, row)
    row["admitted"], row["verdict"] = admitted, why
    return row


def _held_out_seeds() -> list[int]:
    from tuners.settings import EvaluationSettings, load_settings

    return [int(s) for s in load_settings(EvaluationSettings).seeds.seeds()]


def _returns_row(
    task: Task, stats: EpisodeStats, r0: np.ndarray, r100: np.ndarray
) -> dict[str, Any]:
    r = stats.returns
    score = float(normalise(r.mean(), r0.mean(), r100.mean()))
    lo, hi = _episode_interval(r, r0, r100)
    row: dict[str, Any] = {
        "return_mean": float(r.mean()),
        "return_sd": float(r.std(ddof=1)),
        "returns": r.tolist(),
        "score": score,
        "score_se": paired_se(r, r0, r100),
        "score_interval_episodes": [lo, hi],
        # the tracking ids terminate only when the loop diverges (a grasp also on a trip)
        "completed_fraction": float(np.mean(~stats.terminated)),
    }
    if "cost" in stats.sums:
        row["constraint_cost"] = {k: float(v.mean()) for k, v in stats.sums.items()}
    if task.family == "pid-tune":
        costs = [float(i.get("cost", math.nan)) for i in stats.infos]
        row["objective_cost"] = {"episodes": float(np.mean(costs))}
        row["feasible_fraction"] = float(np.mean([bool(i.get("feasible")) for i in stats.infos]))
    if task.family == "grasp":
        assert stats.held is not None and stats.tripped is not None
        row["held_fraction"] = float(stats.held.mean())
        row["trip_fraction"] = float(stats.tripped.mean())
    return row


# ---- the best PID --------------------------------------------------------------------------


def pid_interface(task: Task, gains: Any, options: Any) -> tuple[dict[str, Any], Policy] | None:
    """How a PID runs through the task's environment: the interface arguments and the policy
    (the zero correction of ``residual="pid"``; the constant action that maps to the gains on
    the gain-scheduling and tuning ids, the map widened where the gains lie beyond it: the map
    changes, not the task). ``None`` where it cannot (an error sign the map has no room for)."""
    from gripper_env.envs.spaces import gains_to_action

    g = np.array([gains.P, gains.I, gains.D])
    if "GainSchedule" in task.env_id:
        if options.sign != 1:
            return None
        widest = np.maximum((10.0, 50.0, 0.1), 1.01 * np.abs(g))
        gain_max = (float(widest[0]), float(widest[1]), float(widest[2]))
        action = gains_to_action(g, gain_max, "log")
        return ({"gain_max": gain_max, "derivative_filter": float(gains.N),
                 "pid_options": _options(options)}, constant_policy(action))  # fmt: skip
    if "PIDTune" in task.env_id:
        import gymnasium as gym

        if options.sign != 1:
            return None
        from gripper_env.envs.pid_tune import GripperPIDTuneEnv

        env = gym.make(task.env_id, **task.eval_kwargs).unwrapped
        assert isinstance(env, GripperPIDTuneEnv)
        s = env.settings
        if s.gain_scaling != "relative" or s.gain_center is None:
            return None
        c = np.asarray(s.gain_center)
        if np.any(np.sign(g[:2]) != np.sign(c[:2])):
            return None
        decades = max(s.gain_decades, 1.01 * float(np.max(np.abs(np.log10(g[:2] / c[:2])))))
        d_span = max(s.gain_max[2], 1.01 * abs(g[2] - c[2]))
        gain_max = (s.gain_max[0], s.gain_max[1], d_span)
        action = gains_to_action(g, gain_max, "relative", tuple(c), decades)
        return ({"gain_decades": decades, "gain_max": gain_max,
                 "derivative_filter": float(gains.N)}, constant_policy(action))  # fmt: skip
    return ({"residual": "pid", "pid_gains": (float(gains.P), float(gains.I), float(gains.D)),
             "derivative_filter": float(gains.N), "pid_options": _options(options)},
            constant_policy([0.0]))  # fmt: skip


def _options(options: Any) -> dict[str, Any]:
    return {"output_limits": tuple(float(x) for x in options.output_limits),
            "anti_windup": options.anti_windup, "kb": float(options.kb),
            "derivative_on": options.derivative_on, "sign": int(options.sign)}  # fmt: skip


def _candidates(task: Task, root: Path) -> list[tuple[str, dict[str, Any], Policy, Any]]:
    """``(label, interface, policy, (gains, options) or None)`` of every PID the task's ``pid``
    names."""
    from gripper_env.model.gains_file import load_gains_file

    out: list[tuple[str, dict[str, Any], Policy, Any]] = []
    if "registers" in task.pid:  # a bus servo: its tuned registers, the goal = the reference
        for path in task.pid["registers"]:
            out.append((f"tuned registers ({Path(path).name})",
                        {"registers": str(root / path), "residual": "reference"},
                        constant_policy([0.0]), None))  # fmt: skip
        return out
    seen = set()
    for plant in task.pid.get("plants", []):
        for path in sorted((root / "results" / plant).glob("*.json")):
            try:
                loaded = load_gains_file(path)
            except (ValueError, OSError):
                continue
            g = loaded.gains
            key = (round(g.P, 9), round(g.I, 9), round(g.D, 9), round(g.N, 6), loaded.options.sign)
            if key in seen:
                continue
            made = pid_interface(task, g, loaded.options)
            if made is None:
                continue
            seen.add(key)
            out.append((f"{plant}/{path.stem}", made[0], made[1], (g, loaded.options)))
    return out


def best_pid(
    task: Task,
    anchors: dict[str, Any],
    root: str | Path = ".",
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """The best-PID row (module docstring), with the selection's record."""
    root = Path(root)
    candidates = _candidates(task, root)
    if not candidates:
        raise ValueError(f"task {task.name}: no PID candidates under {root}/results")
    train_plants = _plants(task.train_kwargs)
    picked = []
    for label, iface, policy, pid in candidates:
        kwargs = task.kwargs_with(iface, evaluate=False)
        stats = run_episodes(task.env_id, kwargs, policy, task.selection_seeds,
                             grasp=task.family == "grasp")  # fmt: skip
        entry: dict[str, Any] = {"label": label, "selection_return": float(stats.returns.mean())}
        if task.verdict == "margin":
            from gripper_env.envs.robust import margin_floor_db

            worst = _pid_margin(pid, kwargs, train_plants)
            entry["admitted_on_training"] = bool(worst >= margin_floor_db())
        elif task.verdict == "feasible":
            entry["admitted_on_training"] = all(bool(i.get("feasible")) for i in stats.infos)
        else:
            assert stats.held is not None
            entry["admitted_on_training"] = bool(stats.held.all())
        picked.append((entry, iface, policy))
        log(f"  {task.name}: PID {label}: selection return {entry['selection_return']:.4g}"
            f"{'' if entry['admitted_on_training'] else ' (not admitted)'}")  # fmt: skip
    pool = [p for p in picked if p[0]["admitted_on_training"]] or picked
    entry, iface, policy = max(pool, key=lambda p: p[0]["selection_return"])
    row = judge_policy(task, policy, anchors, iface)
    row["pid"] = entry["label"]
    row["interface"] = _jsonable(iface)
    row["selection"] = {"candidates": [p[0] for p in picked],
                        "among_admitted": any(p[0]["admitted_on_training"] for p in picked),
                        "episodes": len(task.selection_seeds)}  # fmt: skip
    return row


def _pid_margin(pid: Any, kwargs: dict[str, Any], plants: list[str]) -> float:
    """The worst measured gain margin (dB) of a PID over ``plants``: the probe run through the
    simulation core (:func:`tuners.probe.pid_runner`, the same loop as the environment's
    residual PID, a batch per sweep), on the preset's loop."""
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.plants import load_plant
    from tuners.probe import measure_margins, pid_runner

    gains, options = pid
    dist = load_disturbance(kwargs.get("disturbance", "actual"))
    ideal = load_disturbance("ideal")
    worst = math.inf
    for p in plants:
        m = measure_margins(pid_runner(gains, options), load_plant(p), dist, ideal)
        worst = min(worst, math.inf if m.gain_margin_db is None else m.gain_margin_db)
    return worst


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}

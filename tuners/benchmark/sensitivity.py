"""Two checks of the headline's verdict: more held-out seeds, and the stops moved out.

* **Stress** (:func:`stress_check`): every headline candidate on extra held-out seeds of one
  plant (50 seeds of test2 by default, disjoint from the tuning, validation and held-out ones):
  how many runs touched the stop they drew, the jaw's extremes and the admission rule there.
  The rule holds the jaw inside the nearest stop the preset *can* draw, so an admitted row
  should touch on none; this counts it.
* **Stops moved out** (:func:`stops_moved`): the stops' positions are the preset's assumption,
  not a fact of the paper (``configs/disturbances/actual.yaml``). With both stops (and their
  randomisation ranges) ``shift_deg`` further out
  (:func:`gripper_env.evaluation.admission.shift_stops`), every candidate is judged again on
  the held-out seeds, and the robust searches and textbook rules are tuned again under the
  moved stops' rule (the RL rows are judged, not retrained: a retraining takes hours). The
  leaderboard shows how the verdict moves.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.evaluation.admission import shift_stops
from gripper_env.evaluation.scoring import GainScorer, Task, score_trajectory
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from tuners import cli
from tuners.evaluation import with_cost
from tuners.interface import Budget, Tuner

__all__ = ["candidate_runs", "stops_moved", "stress_check"]


def _pid(row: dict[str, Any]) -> PIDGains:
    return PIDGains(row["P"], row["I"], row["D"], row["N"])


def candidate_runs(
    row: dict[str, Any], inputs: cli.Inputs, disturbance: Disturbance, seeds: np.ndarray
) -> dict[str, Any]:
    """The admission rule and mean cost of a candidate (a PID row, or a learned controller's
    row with its study) on ``inputs``' plant under ``disturbance`` over ``seeds``."""
    objective = inputs.objective
    if row["controller"] == "pid":
        _, actual = inputs.settings.options(row["sign"])
        task = Task.build(inputs.plant, inputs.reference, disturbance, seeds, objective=objective,
                          randomize=inputs.settings.randomize, options=actual)  # fmt: skip
        s = GainScorer(task).score(_pid(row).as_array()[None, :])
        return {"admission": s.admission.row(0), "cost": float(s.cost[0])}
    from gripper_env.envs.rollout import policy_trajectory
    from tuners.rl.agents import agent_kwargs, load_agent
    from tuners.rl.controller import policy_admission

    folder = Path(row["tuning"]["study"]).parent
    runs: list[dict[str, Any]] = []
    for k in row["tuning"]["training_seeds"]:
        agent = load_agent(folder / f"seed-{k}" / "best")
        kwargs = agent_kwargs(agent, plant=inputs.plant.name, disturbance=disturbance)
        traj = policy_trajectory(agent, seeds, env_id=agent.env_id, reference=inputs.reference,
                                 **kwargs)  # fmt: skip
        metrics, costs = score_trajectory(traj, objective, disturbance)
        runs += with_cost(metrics, costs)
    onsets = [m["gain_margin_db"]
              for m in (row["measured_margins"].get("per_seed") or {}).values()]  # fmt: skip
    moved = replace(inputs, disturbance=disturbance)
    admission = policy_admission(moved, runs, onsets or [None])
    held = (row.get("admission") or {}).get("measured") or {}
    if "grasp_lost" in held:  # the grasp scenario has no stops to move: the row's verdict
        from gripper_env.evaluation.admission import with_grasp

        admission = with_grasp(admission, held["grasp_lost"], held.get("grasp_reason") or "")
    return {"admission": admission, "cost": float(np.mean([r["cost"] for r in runs]))}


def stress_check(
    evaluations: dict[str, dict[str, Any]],
    inputs: cli.Inputs,
    seeds: np.ndarray,
    log: Callable[..., None] = print,
) -> dict[str, Any]:
    """Every candidate evaluated on ``inputs``' plant on the extra ``seeds``: runs that touched
    the stop they drew, the jaw's extremes and the admission rule there."""
    out: dict[str, Any] = {"plant": inputs.plant.name, "seeds": [int(s) for s in seeds],
                           "rows": {}}  # fmt: skip
    for key, per in evaluations.items():
        row = per.get(inputs.plant.name)
        if row is None or row["kind"] not in ("manual", "baseline", "search", "controller"):
            continue
        r = candidate_runs(row, inputs, inputs.disturbance, seeds)
        m = r["admission"]["measured"]
        out["rows"][key] = {"contact_runs": m.get("contact_runs"), "runs": m.get("runs"),
                            "jaw_min_deg": m.get("jaw_min_deg"),
                            "jaw_max_deg": m.get("jaw_max_deg"),
                            "clearance_deg": m.get("clearance_deg"), "cost": r["cost"],
                            "admitted": r["admission"]["admitted"],
                            "reason": r["admission"]["reason"]}  # fmt: skip
    touching = sum(1 for r in out["rows"].values() if r["contact_runs"])
    log(f"  stress: {len(out['rows'])} candidates on {len(seeds)} more {inputs.plant.name} "
        f"seeds; {touching} touch a stop on some run")  # fmt: skip
    return out


def stops_moved(
    evaluations: dict[str, dict[str, Any]],
    inputs_of: Callable[[str], cli.Inputs],
    plants: Sequence[str],
    shift_deg: float,
    retune: Sequence[Tuner],
    seed: int,
    log: Callable[..., None] = print,
) -> dict[str, Any]:
    """The verdict with both stops ``shift_deg`` further out: every candidate judged again on
    the held-out seeds of every plant, and the ``retune`` tuners (robust rows) tuned again
    under the moved stops. Returns ``{"shift_deg", "stops_deg", "rows": {key: {plant: {cost,
    admission}}}, "retuned": {key: {plant: {...}}}}``."""
    first = inputs_of(plants[0])
    moved = shift_stops(first.disturbance, shift_deg)
    out: dict[str, Any] = {"shift_deg": shift_deg,
                           "limits_deg": list(moved.mechanics.limits_deg or ()),
                           "randomize": {k: list(v) for k, v in moved.randomize.items()
                                         if k.startswith("mechanics.limits_deg")},
                           "rows": {}, "retuned": {}}  # fmt: skip
    for key, per in evaluations.items():
        if set(per) != set(plants):
            continue
        if next(iter(per.values()))["kind"] not in ("manual", "baseline", "search", "controller"):
            continue
        out["rows"][key] = {}
        for p in plants:
            inputs = inputs_of(p)
            seeds = inputs.settings.seeds.seeds()
            out["rows"][key][p] = candidate_runs(per[p], inputs, moved, seeds)
    for tuner in retune:
        inputs = replace(inputs_of(plants[0]), disturbance=moved)
        try:
            tuned = tuner.tune(inputs, Budget(), seed)
        except ValueError as exc:
            log(f"  stops +{shift_deg:g} deg: {tuner.name}: no result ({exc})")
            continue
        assert tuned.gains is not None
        g = tuned.gains
        key = f"{tuner.name} @ {'+'.join(plants)}"
        row = {"controller": "pid", "sign": tuned.sign, "P": g.P, "I": g.I, "D": g.D, "N": g.N,
               "kind": tuner.kind}  # fmt: skip
        out["retuned"][key] = {
            p: {**candidate_runs(row, inputs_of(p), moved, inputs_of(p).settings.seeds.seeds()),
                "P": g.P, "I": g.I, "D": g.D, "N": g.N,
                "tuning_cost": tuned.tuning.get("best_value_tuning")}
            for p in plants
        }  # fmt: skip
        log(f"  stops +{shift_deg:g} deg: {tuner.name} tuned again: P={g.P:.4g} I={g.I:.4g} "
            f"D={g.D:.4g}")  # fmt: skip
    return out

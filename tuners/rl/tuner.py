"""The RL tuners as benchmark rows: :class:`RLTuner` (``rl-tune``) and :class:`RLControllerTuner`
(``rl-controller``), through the :class:`tuners.interface.Tuner` interface."""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import load_plant
from tuners import cli
from tuners.interface import Budget, Tuned

__all__ = ["RLControllerTuner", "RLTuner"]


class RLTuner:
    """The RL PID tuner (:mod:`tuners.rl.tune`) over ``search_seeds`` training seeds, the best
    kept (like Optuna's search seeds), the spread recorded.

    Parameters
    ----------
    plants : list of str, optional
        Robust: one gain set for these identifications.
    search_seeds : int
        Training seeds.
    out : path
        Where the runs go (``<out>/rl/pid-tune-<plants>/seed-<k>``).
    reuse : bool
        Read a seed's run instead of training it again when it was made with the same
        settings, budget and environment (:func:`tuners.rl.tune.train_seeds`).
    """

    kind = "search"

    def __init__(
        self,
        plants: list[str] | None = None,
        search_seeds: int = 3,
        out: str = "runs",
        reuse: bool = True,
    ) -> None:
        self.reuse = reuse
        self.plants = tuple(plants or ())
        self.name = "rl-tune-robust" if self.plants else "rl-tune"
        self.search_seeds = int(search_seeds)
        self.out = Path(out)

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        from tuners.rl.tune import load_tune_settings, train_seeds

        s = load_tune_settings()
        episodes = s.quick_episodes if budget.quick else round(s.episodes * budget.scale)
        names = list(self.plants) or [inputs.plant.name]
        folder = self.out / "rl" / f"pid-tune-{'+'.join(names)}"
        start = time.perf_counter()
        n = 1 if budget.quick else self.search_seeds
        runs = train_seeds(inputs, s, range(seed, seed + n), folder, plants=self.plants,
                           episodes=episodes, progress=False, engine_spec=budget.engine,
                           reuse=self.reuse)  # fmt: skip
        good = [r for r in runs if r["best"] is not None]
        if not good:
            raise ValueError(f"{self.name} on {'+'.join(names)}: no seed evaluated feasible "
                             "gains off the map's bounds")  # fmt: skip
        best = min(good, key=lambda r: r["best"]["tuning_cost"])
        costs = np.array([r["best"]["tuning_cost"] for r in good])
        tuning = {
            "algo": "ppo",
            "tuned_on": names,
            "episodes_per_seed": episodes,
            "chosen_seed": best["seed"],
            "at_episodes": best["best"]["episodes"],
            "best_value_tuning": best["best"]["tuning_cost"],
            "center": best["center"],
            "on_bound": [],
            "history": _best_so_far(best),
            "best_cost": {"min": float(costs.min()), "median": float(np.median(costs)),
                          "max": float(costs.max())},
            "per_seed": [{"seed": r["seed"],
                          "best_value_tuning": None if r["best"] is None
                          else r["best"]["tuning_cost"],
                          "at_episodes": None if r["best"] is None else r["best"]["episodes"],
                          "gains": None if r["best"] is None else r["best"]["gains"]}
                         for r in runs],
        }  # fmt: skip
        _held_out(inputs, tuning["per_seed"], names)
        held = [e["held_out_cost"] for e in tuning["per_seed"] if e["held_out_cost"] is not None]
        tuning["held_out_cost"] = {"median": float(np.median(held)), "min": float(np.min(held)),
                                   "max": float(np.max(held)), "n": len(held)}  # fmt: skip
        tuning["curves"] = {str(r["seed"]): [[e["episodes"], e["tuning_cost"] if e["feasible"]
                                              else None] for e in r["evaluations"]]
                            for r in runs}  # fmt: skip
        used = sum(r["episodes"] + r["selection_episodes"] for r in runs)
        return Tuned(best["gains"], 1, tuning, episodes=int(used),
                     wall_s=time.perf_counter() - start, label=self.name)  # fmt: skip


def _held_out(inputs: cli.Inputs, per_seed: list[dict[str, Any]], plants: list[str]) -> None:
    """Each seed's gains on the held-out seeds of the actual model (mean over ``plants``): the
    cost a gains file of that seed would report, and the admission rule's verdict
    (:mod:`gripper_env.evaluation.admission`) on every plant."""
    ideal_opts, actual_opts = inputs.settings.options(1)
    on = [inputs.for_plant(load_plant(p)) for p in plants]  # loaded once for every seed
    for e in per_seed:
        e["held_out_cost"] = e["meets_constraints"] = e["admission_reason"] = None
        if e["gains"] is None:
            continue
        costs, meets, reasons = [], True, []
        for plant_inputs in on:
            ev = cli.evaluate_inputs(plant_inputs, PIDGains(*e["gains"]), actual_opts,
                                     ideal_opts, cross=False)  # fmt: skip
            costs.append(float(ev.actual["mean"]["cost"]))
            meets = meets and bool(ev.admission["admitted"])
            if not ev.admission["admitted"]:
                reasons.append(f"on {plant_inputs.plant.name}: {ev.admission['reason']}")
        e["held_out_cost"] = float(np.mean(costs))
        e["meets_constraints"] = meets  # the admission rule on the held-out runs, every plant
        e["admission_reason"] = reasons[0] if reasons else None


def _best_so_far(run: Mapping[str, Any]) -> list[tuple[int, float]]:
    """The run's budget curve: ``(episodes used, best feasible tuning cost so far)``."""
    curve, best = [], float("inf")
    per_eval = run["selection_episodes"] / max(1, len(run["evaluations"]))
    for i, e in enumerate(run["evaluations"]):
        if e["feasible"] and not e["on_bound"] and e["tuning_cost"] < best:
            best = e["tuning_cost"]
        if best < float("inf"):
            curve.append((int(e["episodes"] + (i + 1) * per_eval), best))
    return curve


class RLControllerTuner:
    """The RL controller (:mod:`tuners.rl.controller`): a residual PPO policy on the PID of the
    row ``base``, trained over ``seeds`` (a count, or per plant ``{test2: 5, default: 3}``).

    A study whose settings, base gains, seeds and budget match one already in ``out`` is
    reused (``reuse``): training is the expensive part of the benchmark.
    """

    kind = "controller"

    def __init__(
        self,
        base: str = "optuna",
        seeds: int | dict[str, int] = 3,
        plants: list[str] | None = None,
        out: str = "runs",
        reuse: bool = True,
    ) -> None:
        self.base = base
        self.requires = (base,)
        self.seeds = seeds
        self.plants = tuple(plants or ())
        self.name = "rl-controller-robust" if self.plants else "rl-controller"
        self.out = Path(out)
        self.reuse = reuse
        self._bound: dict[str, Tuned] = {}

    def bind(self, rows: Mapping[str, Tuned]) -> None:
        """The results of the rows this tuner builds on (its base PID)."""
        if self.base not in rows or rows[self.base].gains is None:
            raise ValueError(f"{self.name} needs the row {self.base!r} (its base PID) first")
        self._bound = dict(rows)

    def _n_seeds(self, plant: str) -> int:
        if isinstance(self.seeds, int):
            return self.seeds
        return int(self.seeds.get(plant, self.seeds.get("default", 3)))

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        from tuners.rl.controller import controller_study, load_controller_settings, write_study

        base_row = self._bound.get(self.base)
        if base_row is None or base_row.gains is None:
            raise ValueError(f"{self.name}: bind the base row {self.base!r} first")
        base: PIDGains = base_row.gains
        s = load_controller_settings()
        steps = s.quick_timesteps if budget.quick else round(s.timesteps * budget.scale)
        seeds = list(range(seed, seed + (1 if budget.quick else self._n_seeds(inputs.plant.name))))
        names = list(self.plants) or [inputs.plant.name]
        name = f"controller-{'+'.join(names)}"
        path = self.out / "rl" / name / "study.json"
        start = time.perf_counter()
        limits = inputs.objective.constraints.limits()
        study = _reusable(path, s.model_dump(), base, seeds, steps, limits) if self.reuse else None
        if study is None:
            study = controller_study(inputs, base, seeds=seeds, settings=s, plants=self.plants,
                                     out=self.out, timesteps=steps, progress=False,
                                     log=lambda m: None, engine_spec=budget.engine)  # fmt: skip
            write_study(study, self.out, name)
            study = json.loads(path.read_text())
        if inputs.objective.constraints.grasp and any(
            "grasp" not in v for v in study["per_plant"].values()
        ):  # a study trained before the grasp check: its saved policies run it now
            from tuners.rl.controller import add_grasp

            add_grasp(study, inputs, path.parent)
            write_study(study, self.out, name)
        tuning = {
            "algo": "ppo",
            "base_row": self.base,
            "tuned_on": names,
            "training_seeds": seeds,
            "timesteps_per_seed": steps,
            "first_step_mean_beats_base": study["curve"]["first_step_mean_beats_base"],
            "study": str(path),
        }
        episodes = round(len(seeds) * steps * 0.020 / inputs.reference.duration_s)
        return Tuned(None, 1, tuning, episodes=episodes, wall_s=time.perf_counter() - start,
                     label=self.name, study=study)  # fmt: skip


def _reusable(
    path: Path, settings: dict[str, Any], base: PIDGains, seeds: list[int], steps: int,
    limits: dict[str, float],
) -> dict[str, Any] | None:  # fmt: skip
    """The study at ``path`` if it was made with these settings, base, seeds and budget, and
    judged by these limits of the admission rule (its checkpoints were chosen by the floor, its
    verdicts recorded; the grasp scenario, if the study lacks it, runs afterwards)."""
    try:
        study = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    same = (
        study.get("settings") == json.loads(json.dumps(settings))
        and np.allclose(study.get("base_gains") or [], [base.P, base.I, base.D, base.N])
        and [e["seed"] for e in study.get("seeds", [])] == seeds
        and study.get("requested_timesteps") == steps
        and all(
            {k: v for k, v in ((p.get("admission") or {}).get("limits") or {}).items()
             if k in limits} == json.loads(json.dumps(limits))
            for p in (study.get("per_plant") or {}).values()
        )
    )  # fmt: skip
    return study if same else None

"""Optuna as a tuner: the benchmark's ``optuna-*`` rows (:class:`OptunaTuner`)."""

from __future__ import annotations

import time

from gripper_env.model.plants import load_plant
from tuners import cli
from tuners.interface import Budget, Tuned
from tuners.optuna.sampler import SAMPLERS, make_sampler
from tuners.optuna.search import best_of, search, seed_summary, tuner_name
from tuners.optuna.warm_start import textbook_designs
from tuners.settings import OptunaSettings, load_settings

__all__ = ["OptunaTuner"]


class OptunaTuner:
    """Searches in memory with one sampler over ``search_seeds`` independent seeds (the best
    feasible kept, the spread recorded); ``trials`` finished trials each.

    Parameters
    ----------
    sampler : str
        ``tpe``, ``cmaes`` or ``random``.
    plants : list of str, optional
        Robust: one gain set for these identifications (mean cost, constraints on each).
    trials, search_seeds : int, optional
        Default: ``configs/tuners/optuna.yaml``'s.
    quick_trials, quick_search_seeds : int
        The quick budget.
    """

    kind = "search"

    def __init__(
        self,
        sampler: str = "tpe",
        plants: list[str] | None = None,
        trials: int | None = None,
        search_seeds: int | None = None,
        quick_trials: int = 32,
        quick_search_seeds: int = 1,
    ) -> None:
        if sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {sampler!r}; choose one of {', '.join(SAMPLERS)}")
        self.settings = load_settings(OptunaSettings)
        make_sampler(sampler, 0, self.settings, False)  # checks that it can be made
        self.sampler = sampler
        self.plants = tuple(plants or ())
        self.name = tuner_name(sampler, False, robust=bool(self.plants))
        self.trials = trials or self.settings.trials
        self.search_seeds = search_seeds or self.settings.search_seeds
        self.quick = (quick_trials, quick_search_seeds)

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        trials, n_seeds = self.quick if budget.quick else (self.trials, self.search_seeds)
        trials = max(1, round(trials * budget.scale))
        start = time.perf_counter()
        results, episodes, space = [], 0, None
        plants = [load_plant(p) for p in self.plants] or [inputs.plant]
        warm = (textbook_designs(tuple(plants), inputs.disturbance, inputs.settings.pid.N)
                if self.settings.warm_start else [])  # fmt: skip
        for i in range(n_seeds):
            result, scorer, space = search(
                inputs, self.settings, n_trials=trials, sampler_name=self.sampler,
                seed=seed + i, plants=self.plants, warm_start=warm,
            )  # fmt: skip
            results.append(result)
            episodes += scorer.episodes
        assert space is not None
        best = results[best_of(results)]
        tuning = {
            "infeasible": best.infeasible_line(self.name),
            "sampler": self.sampler,
            "trials_per_seed": trials,
            "tuned_on": list(self.plants) or [inputs.plant.name],
            "feasible": best.feasible,
            "best_value_tuning": best.best_value,
            "history": best.history,
            "on_bound": space.on_bound(best.gains),
            "search_space": space.as_dict(),
            **seed_summary(results, [seed + i for i in range(n_seeds)]),
        }
        return Tuned(best.gains, 1, tuning, episodes=episodes,
                     wall_s=time.perf_counter() - start, label=self.name)  # fmt: skip

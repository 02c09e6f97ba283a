"""Searches in memory (the benchmark's), their tasks and scorers, and the spread over seeds."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import optuna

from gripper_env.evaluation.scoring import GainScorer
from gripper_env.model.pid import PIDGains
from tuners import cli
from tuners.optuna.study import StudyResult, run_search
from tuners.optuna.warm_start import textbook_designs
from tuners.search_space import SearchSpace, search_space
from tuners.settings import OptunaSettings
from tuners.tasks import make_scorer, make_task

__all__ = ["best_of", "make_scorer", "make_task", "search", "seed_summary", "tuner_name"]


def search(
    inputs: cli.Inputs,
    settings: OptunaSettings,
    *,
    n_trials: int,
    sampler_name: str = "tpe",
    seed: int = 0,
    progress: bool = False,
    plants: Sequence[str] = (),
    warm_start: Sequence[PIDGains] | None = None,
) -> tuple[StudyResult, GainScorer, SearchSpace]:
    """One single-objective search in memory (no storage): the benchmark's entry point.
    ``warm_start``: the gain sets enqueued first (default the textbook designs on the task's
    plants, :func:`tuners.optuna.warm_start.textbook_designs`; ``()`` for none)."""
    scorer = make_scorer(inputs, settings, plants)
    space = search_space(scorer.task.plants, inputs.disturbance, settings)
    if warm_start is None:
        warm_start = (
            textbook_designs(scorer.task.plants, inputs.disturbance, inputs.settings.pid.N)
            if settings.warm_start
            else ()
        )
    study = optuna.create_study(
        study_name=f"{inputs.plant.name}-{sampler_name}-s{seed}",
        sampler=optuna.samplers.RandomSampler(seed=seed),
    )
    result = run_search(
        study, scorer, space, settings, n_trials, inputs.settings.pid.N,
        sampler_name=sampler_name, seed=seed, progress=progress, warm_start=warm_start,
    )  # fmt: skip
    return result, scorer, space


def seed_summary(results: Sequence[StudyResult], seeds: Sequence[int]) -> dict[str, Any]:
    """The spread of the best cost over independent search seeds, and each seed's result."""
    costs = np.array([r.best_value for r in results])
    return {
        "search_seeds": list(seeds),
        "best_cost": {
            "min": float(costs.min()),
            "median": float(np.median(costs)),
            "max": float(costs.max()),
        },
        "per_seed": [
            {
                "seed": s,
                "best_value_tuning": r.best_value,
                "feasible": r.feasible,
                "P": r.gains.P,
                "I": r.gains.I,
                "D": r.gains.D,
                "N": r.gains.N,
            }
            for s, r in zip(seeds, results, strict=True)
        ],
    }


# ----------------------------------------------------------------------------------------------
# Command line


def best_of(results: Sequence[StudyResult]) -> int:
    """Index of the search seed to keep: the best feasible tuning cost (else the first)."""
    feasible = [i for i, r in enumerate(results) if r.feasible]
    if not feasible:
        return 0
    return min(feasible, key=lambda i: results[i].best_value)


def tuner_name(sampler: str, multi: bool, robust: bool = False) -> str:
    """File stem of the result: ``optuna`` (TPE), ``optuna-cmaes``, ``optuna-random``,
    ``optuna-mo``; ``-robust`` when tuned on several plants."""
    name = "optuna-mo" if multi else ("optuna" if sampler == "tpe" else f"optuna-{sampler}")
    return f"{name}-robust" if robust else name

"""Optuna samplers by name: TPE (multivariate, constant liar), CMA-ES, random."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tuners.settings import OptunaSettings

__all__ = ["SAMPLERS", "make_sampler"]

#: The sampler names ``--sampler`` takes.
SAMPLERS = ("tpe", "cmaes", "random")


def make_sampler(name: str, seed: int, settings: OptunaSettings, multi: bool) -> Any:
    """The sampler: TPE (multivariate, constant liar for batches), CMA-ES, or random."""
    import optuna

    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    if name == "cmaes":
        if multi:
            raise ValueError(
                "--sampler cmaes searches one objective; use tpe with --multi-objective"
            )
        try:
            import cmaes  # noqa: F401
        except ImportError:
            raise ValueError(
                "--sampler cmaes needs the 'cmaes' package: pip install cmaes"
            ) from None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.CmaEsSampler(
                seed=seed,
                n_startup_trials=settings.n_startup_trials,
                warn_independent_sampling=False,
            )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(
            seed=seed,
            n_startup_trials=settings.n_startup_trials,
            multivariate=True,
            constant_liar=True,
        )

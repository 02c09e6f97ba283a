"""Textbook rules as tuners: the benchmark's ``classical-*`` rows (:class:`ClassicalTuner`)."""

from __future__ import annotations

import time
from typing import Any

from gripper_env.model.pid import PIDGains
from tuners import cli
from tuners.classical.constrained import KNOBS, constrained_design
from tuners.classical.rules import METHODS, design, require_stable
from tuners.interface import Budget, Tuned
from tuners.settings import ClassicalSettings, OptunaSettings, load_settings
from tuners.tasks import make_scorer

__all__ = ["ClassicalTuner", "tune_rule", "tuner_name"]


def tuner_name(method: str, fixed: bool, robust: bool = False) -> str:
    """``classical-<method>`` (knob set under the constraints), ``-fixed``, ``-robust``."""
    return f"classical-{method}" + ("-fixed" if fixed else "") + ("-robust" if robust else "")


def tune_rule(
    method: str,
    inputs: cli.Inputs,
    settings: ClassicalSettings,
    *,
    fixed: bool = False,
    plants: list[str] | tuple[str, ...] | None = None,
    optuna_settings: OptunaSettings | None = None,
) -> tuple[PIDGains, dict[str, Any]]:
    """The rule's gains: at its fixed setting, or with its knob set under the constraints (on
    the tuning task of ``plants``, default the inputs' plant).

    Raises
    ------
    ValueError
        The plant is not open-loop stable (:func:`~tuners.classical.rules.require_stable`).
    """
    require_stable(inputs.plant)
    n = inputs.settings.pid.N
    if fixed or method not in KNOBS:
        return design(method, inputs.plant, inputs.disturbance, settings, n)
    scorer = make_scorer(inputs, optuna_settings, list(plants or ()))
    gains, tuning = constrained_design(
        method, inputs.plant, inputs.disturbance, settings, scorer, n
    )
    tuning["tuned_on"] = [p.name for p in scorer.task.plants]
    return gains, tuning


class ClassicalTuner:
    """A textbook rule: its knob set under the constraints (``kind`` baseline), or at its fixed
    setting (``fixed``: a reference, never ranked)."""

    def __init__(self, method: str, fixed: bool = False, plants: list[str] | None = None) -> None:
        if method not in METHODS:
            raise ValueError(f"unknown classical method {method!r}; choose one of "
                             f"{', '.join(METHODS)}")  # fmt: skip
        self.method = method
        self.fixed = fixed or method not in KNOBS
        self.plants = tuple(plants or ())
        self.kind = "reference" if self.fixed else "baseline"
        self.name = tuner_name(method, self.fixed, bool(self.plants))

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        start = time.perf_counter()
        gains, tuning = tune_rule(
            self.method, inputs, load_settings(ClassicalSettings), fixed=self.fixed,
            plants=self.plants,
        )  # fmt: skip
        return Tuned(gains, 1, tuning, episodes=int(tuning.get("episodes", 0)),
                     wall_s=time.perf_counter() - start, label=self.method)  # fmt: skip

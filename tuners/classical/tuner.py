"""Textbook rules as tuners: the benchmark's ``classical-*`` rows (:class:`ClassicalTuner`).

A rule reads its design model off one plant, and the model is the engineer's choice as much as
the rule's knob: a robust row (tuned on several identifications of one gripper) tries each of
them and the nominal of the set (:func:`nominal_plant`) as its design model, with its knob set
under the admission rule on all of them, and keeps the best admitted design
(:func:`tune_rule`'s ``design_models``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import Plant, load_plant
from tuners import cli
from tuners.classical.constrained import KNOBS, constrained_design
from tuners.classical.rules import METHODS, design, fit_fopdt, require_stable
from tuners.interface import Budget, Tuned
from tuners.settings import ClassicalSettings, OptunaSettings, load_settings
from tuners.tasks import make_scorer

__all__ = ["NOMINAL", "ClassicalTuner", "nominal_plant", "tune_rule", "tuner_name"]

#: The design model that stands for the nominal of a set of identifications.
NOMINAL = "nominal"


def tuner_name(method: str, fixed: bool, robust: bool = False) -> str:
    """``classical-<method>`` (knob set under the constraints), ``-fixed``, ``-robust``."""
    return f"classical-{method}" + ("-fixed" if fixed else "") + ("-robust" if robust else "")


def nominal_plant(
    plants: Sequence[Plant], disturbance: Disturbance, settings: ClassicalSettings
) -> Plant:
    """The nominal of a set of identifications: the first-order lag ``k / (tau s + 1)`` with the
    mean of their FOPDT gains and the geometric mean of their FOPDT time constants (the centre
    of the set on the log scale its time constants spread over: 97, 48 and 10 ms for test2,
    test3 and test4)."""
    if not plants:
        raise ValueError("the nominal of a set of identifications needs at least one")
    models = [fit_fopdt(p, disturbance, settings) for p in plants]
    k = sum(m.k for m in models) / len(models)
    tau = math.exp(sum(math.log(m.tau_s) for m in models) / len(models))
    names = ", ".join(p.name for p in plants)
    return Plant.from_coefficients(
        [k], [tau, 1.0], name=NOMINAL, dt_s=plants[0].dt_s,
        jaw_range_deg=plants[0].jaw_range_deg,
        description=f"nominal of {names}: k = {k:.4g}, tau = {1e3 * tau:.4g} ms",
    )  # fmt: skip


def _binding(exc: ValueError) -> str:
    """What an infeasible knob scan found at its nearest setting (its message's tail)."""
    text = str(exc)
    mark = "; binding constraint "
    return text[text.index(mark) + 2 :] if mark in text else text


def tune_rule(
    method: str,
    inputs: cli.Inputs,
    settings: ClassicalSettings,
    *,
    fixed: bool = False,
    plants: list[str] | tuple[str, ...] | None = None,
    optuna_settings: OptunaSettings | None = None,
    design_models: Sequence[str] = (),
) -> tuple[PIDGains, dict[str, Any]]:
    """The rule's gains: at its fixed setting, or with its knob set under the constraints (on
    the tuning task of ``plants``, default the inputs' plant).

    The rule designs on the inputs' plant, or, with ``design_models`` (plant names, and
    :data:`NOMINAL` for the nominal of ``plants``), on each of them with its knob set under the
    constraints, keeping the design of least tuning cost; the record names it
    (``design_model``) and what every model gave (``design_models``).

    Raises
    ------
    ValueError
        The plant is not open-loop stable (:func:`~tuners.classical.rules.require_stable`), or
        no setting of the knob meets the constraints (on any design model: each one's binding
        constraint named).
    """
    require_stable(inputs.plant)
    n = inputs.settings.pid.N
    if fixed or method not in KNOBS:
        return design(method, inputs.plant, inputs.disturbance, settings, n)
    scorer = make_scorer(inputs, optuna_settings, list(plants or ()))
    tuned_on = [p.name for p in scorer.task.plants]
    if not design_models:
        gains, tuning = constrained_design(
            method, inputs.plant, inputs.disturbance, settings, scorer, n
        )
        tuning["tuned_on"] = tuned_on
        return gains, tuning
    tried: dict[str, dict[str, Any]] = {}
    best: tuple[str, PIDGains, dict[str, Any]] | None = None
    episodes = 0
    for name in design_models:
        model = (nominal_plant(scorer.task.plants, inputs.disturbance, settings)
                 if name == NOMINAL else load_plant(name))  # fmt: skip
        try:
            gains, tuning = constrained_design(method, model, inputs.disturbance, settings,
                                               scorer, n)  # fmt: skip
        except ValueError as exc:
            tried[name] = {"admitted": False, "reason": _binding(exc)}
            continue
        episodes += int(tuning.get("episodes", 0))
        cost = float(tuning["best_value_tuning"])
        tried[name] = {"admitted": True, "tuning_cost": cost, "knob": tuning["knob"]["value"],
                       "gains": [gains.P, gains.I, gains.D, gains.N]}  # fmt: skip
        if best is None or cost < best[2]["best_value_tuning"]:
            best = (name, gains, tuning)
    knob = KNOBS[method]
    if best is None:
        lim = scorer.task.objective.constraints
        clearance = lim.limits(scorer.task.search)["stop_clearance_deg"]
        raise ValueError(
            f"{method}: infeasible: no setting of {knob.name} in [{knob.low:g}, {knob.high:g}] "
            f"meets the admission rule (Ms <= {lim.ms_max:g}, GM >= {lim.gm_min_db:g} dB with "
            f"the hold, settled, no stall, {clearance:g} deg inside the nearest stops the preset "
            "can draw) on any design model: "
            + "; ".join(f"designed on {m}: {t['reason']}" for m, t in tried.items())
        )
    name, gains, tuning = best
    tuning.update(tuned_on=tuned_on, design_model=name, design_models=tried, episodes=episodes)
    return gains, tuning


class ClassicalTuner:
    """A textbook rule: its knob set under the constraints (``kind`` baseline), or at its fixed
    setting (``fixed``: a reference, never ranked). A robust one (``plants``) tries every one of
    ``plants`` and their nominal as its design model (``design_models``, by default those)."""

    def __init__(
        self,
        method: str,
        fixed: bool = False,
        plants: list[str] | None = None,
        design_models: list[str] | None = None,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"unknown classical method {method!r}; choose one of "
                             f"{', '.join(METHODS)}")  # fmt: skip
        self.method = method
        self.fixed = fixed or method not in KNOBS
        self.plants = tuple(plants or ())
        self.kind = "reference" if self.fixed else "baseline"
        self.name = tuner_name(method, self.fixed, bool(self.plants))
        if design_models is None:
            design_models = [*self.plants, NOMINAL] if self.plants else []
        for m in design_models:
            if m != NOMINAL and m not in self.plants:
                raise ValueError(f"design model {m!r} is not one of the row's plants "
                                 f"{list(self.plants)} nor {NOMINAL!r}")  # fmt: skip
        self.design_models = tuple(design_models)

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        start = time.perf_counter()
        gains, tuning = tune_rule(
            self.method, inputs, load_settings(ClassicalSettings), fixed=self.fixed,
            plants=self.plants, design_models=self.design_models,
        )  # fmt: skip
        return Tuned(gains, 1, tuning, episodes=int(tuning.get("episodes", 0)),
                     wall_s=time.perf_counter() - start, label=self.method)  # fmt: skip

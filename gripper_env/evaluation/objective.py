"""The one tuning objective: what a tuner minimises, and the robustness it must keep.

A controller is judged by what the jaw does on the actual gripper (``configs/objective.yaml``):

``cost = w_iae IAE + w_os overshoot + w_ts settling + w_stall stall + w_sat saturation
+ w_u servo effort (+ w_sd SD gap + w_e controller effort, both 0 by default)``

per run, averaged over runs (disturbance seeds, plants), where

* **IAE** (deg s): tracking error of the true jaw angle, the first measure of a position loop;
* **overshoot** (%): the worse of grip and un-grip; visible on the actual gripper because its
  stops lie beyond the references;
* **settling time** (s, mean of grip and un-grip): with a band no tighter than the friction band
  (:attr:`Objective.settling_band`), else a stick-slip jaw "never settles" whatever the gains;
  a move that never settles counts the run's duration;
* **stall** (s): the jaw held by a stop with the servo command a whole stall band beyond it,
  i.e. full stall current (``mechanics.stall_band_deg``); on hardware that is heat and, on an
  object, crushing force;
* **saturation** (s): the command clipped to the servo range;
* **servo effort** (deg): total variation of the command the servo actually receives (50 Hz,
  whole degrees): chatter that wears the gear train. Not the 1 kHz PID output, whose variation
  sensor noise inflates by ~6,800 deg per unit of P while the servo never sees most of it.

The paper's SD and SD gap are reported everywhere but not optimised by default: a response that
overshoots has an SD *closer* to the reference's than one that does not (the SD gap rewards
overshoot).

What a deployable controller must do is a constraint, not a weight (:attr:`Objective.constraints`,
the admission rule of :mod:`gripper_env.evaluation.admission`): ``Ms <= 1.6`` and a gain margin of
at least 6 dB on the loop as it runs, with the servo's command hold
(:mod:`gripper_env.evaluation.stability`; 6 dB and Ms 1.6 are the usual textbook floors, Astrom
and Hagglund; Ms <= 1.6 alone implies GM >= 8.5 dB and PM >= 36 deg), every run settled, no stall,
and the jaw at least ``stop_clearance_deg`` inside the nearest stop the preset can draw on every
run. Contact with a stop is therefore not in the cost: a search that touches cannot win, it is
refused (the stall weight only grades what the constraint already refuses on the step profile,
and still counts where an object makes the jaw stall on purpose). Tuners that support
constraints (Optuna's TPE and random search) get them as constraints; the others (CMA-ES, the
textbook knob scans, RL) minimise :meth:`Objective.penalised`, in which any infeasible gain set
costs at least ``infeasible_penalty`` more than the feasible ones (graded by how far it is from
feasible).

Stable runs are capped at ``max_cost`` and diverged runs cost ``unstable_cost`` (finite and
clearly the worst), so optimisers never see ``inf`` or NaN.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from gripper_env.evaluation.metrics import Metrics
from gripper_env.io.config import config_file, load_yaml, validate
from gripper_env.model.disturbances import Disturbance

__all__ = ["COST_TERMS", "Constraints", "Objective", "load_objective"]

#: The terms of the cost, in report order.
COST_TERMS = (
    "iae",
    "overshoot_pct",
    "settling_time_s",
    "stall_s",
    "saturation_s",
    "servo_effort_deg",
    "sd_gap_deg",
    "control_effort",
)

_STRICT = ConfigDict(extra="forbid")


class Weights(BaseModel):
    """Weights of the cost terms (each >= 0; see the module docstring for units)."""

    model_config = _STRICT

    iae: float = Field(1.0, ge=0)
    overshoot_pct: float = Field(0.5, ge=0)
    settling_time_s: float = Field(2.0, ge=0)
    stall_s: float = Field(10.0, ge=0)
    saturation_s: float = Field(1.0, ge=0)
    servo_effort_deg: float = Field(0.001, ge=0)
    sd_gap_deg: float = Field(0.0, ge=0)
    control_effort: float = Field(0.0, ge=0)


class Constraints(BaseModel):
    """The admission rule's limits (:mod:`gripper_env.evaluation.admission`): robustness on the
    loop as it runs (with the hold), the jaw's clearance from the nearest stop the preset can
    draw, and whether the grasp scenario is part of it. Settling and no stall have no limit to
    set: every run must settle and none may stall."""

    model_config = _STRICT

    ms_max: float = Field(1.6, gt=1.0)
    gm_min_db: float = Field(6.0, ge=0.0)
    stop_clearance_deg: float = Field(0.0, ge=0.0)
    search_backoff_deg: float = Field(1.0, ge=0.0)
    grasp: bool = True

    @property
    def measured_gm_min_db(self) -> float:
        """The gain margin (dB) that ``Ms <= ms_max`` guarantees a linear loop,
        ``20 log10(Ms / (Ms - 1))``: what a learned controller's measured limit-cycle onset must
        reach (its ``Ms`` cannot be measured)."""
        return 20.0 * math.log10(self.ms_max / (self.ms_max - 1.0))

    def limits(self, search: bool = False) -> dict[str, float]:
        """The limits as :meth:`gripper_env.evaluation.admission.Admission.build` takes them:
        the judge's, or with ``search`` a search's (the stop clearance backed off by
        ``search_backoff_deg``: a search sees the few friction and noise draws of its tuning
        seeds, the judge others)."""
        clearance = self.stop_clearance_deg + (self.search_backoff_deg if search else 0.0)
        return {
            "ms_max": self.ms_max,
            "gm_min_db": self.gm_min_db,
            "stop_clearance_deg": clearance,
            "measured_gm_min_db": self.measured_gm_min_db,
        }


class Objective(BaseModel):
    """A tuning objective: weights, constraints, the scored signal and the caps.

    Attributes
    ----------
    weights : Weights
        Cost per unit of each term.
    constraints : Constraints
        ``Ms`` and gain-margin limits with the servo's command hold.
    signal : {"true", "measured"}
        Score the true jaw angle (what the jaw does; default) or the measured one.
    settling_band : "friction" or float
        Floor of the settling band (deg): ``friction`` = the disturbance's friction band
        (:meth:`settling_band_deg`), or a number.
    infeasible_penalty : float
        What :meth:`penalised` adds to an infeasible gain set's cost, at least.
    max_cost, unstable_cost : float
        Cap of a stable run's cost; the cost of a diverged run.

    Examples
    --------
    >>> from gripper_env.sim import simulate
    >>> from gripper_env.evaluation.metrics import compute_metrics
    >>> objective = load_objective()
    >>> traj = simulate("test2", "step", gains=[(1.0, 9.0, -0.001)], disturbance="ideal")
    >>> float(objective.cost(compute_metrics(traj, "true"))[0]) < 100
    True
    """

    model_config = _STRICT

    name: str = "default"
    weights: Weights = Weights()
    constraints: Constraints = Constraints()
    signal: Literal["true", "measured"] = "true"
    settling_band: Literal["friction"] | float = "friction"
    infeasible_penalty: float = Field(100.0, gt=0)
    max_cost: float = Field(1000.0, gt=0)
    unstable_cost: float = Field(10000.0, gt=0)

    @field_validator("signal", mode="before")
    @classmethod
    def _yaml_true(cls, v: object) -> object:
        return "true" if v is True else v  # an unquoted YAML `true`

    @field_validator("settling_band")
    @classmethod
    def _band(cls, v: object) -> object:
        if isinstance(v, float) and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"must be 'friction' or a number of deg >= 0, got {v!r}")
        return v

    @model_validator(mode="after")
    def _order(self) -> Objective:
        if self.unstable_cost <= self.max_cost:
            raise ValueError("unstable_cost must exceed max_cost so a diverged run is the worst")
        return self

    def settling_band_deg(self, disturbance: Disturbance) -> float:
        """The settling band's floor (deg) on ``disturbance``: a number, or its friction band
        (the largest stiction band ``S`` its randomisation can draw, plus backlash)."""
        if not isinstance(self.settling_band, str):
            return float(self.settling_band)
        return disturbance.friction_band_deg

    def terms(self, metrics: Metrics, duration_s: float | None = None) -> dict[str, np.ndarray]:
        """The unweighted terms per run (finite for stable runs; NaN counters count 0)."""
        settle = np.stack([metrics.grip["settling_time_s"], metrics.ungrip["settling_time_s"]])
        cap = duration_s if duration_s is not None else 1e3
        settle = np.where(np.isfinite(settle), settle, cap).mean(axis=0)
        overshoot = np.maximum(metrics.grip["overshoot_pct"], metrics.ungrip["overshoot_pct"])
        run = metrics.run

        def known(x: np.ndarray) -> np.ndarray:
            return np.where(np.isnan(x), 0.0, x)

        return {
            "iae": run["iae"],
            "overshoot_pct": np.where(np.isfinite(overshoot), overshoot, 0.0),
            "settling_time_s": settle,
            "stall_s": known(run["stall_s"]),
            "saturation_s": run["saturation_s"],
            "servo_effort_deg": known(run["servo_effort_deg"]),
            "sd_gap_deg": run["sd_gap_deg"],
            "control_effort": run["control_effort"],
        }

    def cost(self, metrics: Metrics, duration_s: float | None = None) -> np.ndarray:
        """Cost per run (shape (B,)), finite: ``unstable_cost`` for diverged runs."""
        terms = self.terms(metrics, duration_s)
        w = self.weights.model_dump()
        stable = np.asarray(metrics.stable, dtype=bool)
        total = np.zeros(len(stable))
        for name in COST_TERMS:
            if w[name] == 0.0:
                continue
            value = np.where(stable, terms[name], 0.0)
            total += w[name] * np.where(np.isfinite(value), value, self.max_cost)
        total = np.minimum(total, self.max_cost)
        return np.where(stable, total, self.unstable_cost)

    def penalised(self, cost: np.ndarray, violation: np.ndarray) -> np.ndarray:
        """``cost`` with the constraints folded in, for tuners that take no constraints:
        ``cost + infeasible_penalty * (1 + violation)`` where ``violation > 0``."""
        v = np.asarray(violation, dtype=float)
        return np.where(v > 0, cost + self.infeasible_penalty * (1.0 + v), cost)


def load_objective(
    objective: str | os.PathLike[str] | Mapping[str, Any] | Objective | None = None,
) -> Objective:
    """The default objective (``configs/objective.yaml``), another file, or a dict."""
    if isinstance(objective, Objective):
        return objective
    if isinstance(objective, Mapping):
        return validate(Objective, dict(objective), "objective dict")
    path = config_file("objective.yaml") if objective is None else objective
    return validate(Objective, load_yaml(path), str(path))

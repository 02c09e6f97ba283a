"""The one tuning objective: a weighted cost of the metrics, shared by every tuner.

``cost = w_iae * IAE + w_os * max(grip, un-grip overshoot %) + w_sd * SD gap
+ w_ts * mean(grip, un-grip settling time) + w_u * control effort``, per run, with weights from
``configs/objective.yaml``. A run that never settles counts the whole segment as its settling
time; stable runs are capped at ``max_cost`` and diverged runs cost ``unstable_cost`` (finite and
clearly the worst), so optimisers never see ``inf`` or NaN.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from gripper_env.config import CONFIG_DIR, load_yaml, validate
from gripper_env.metrics import Metrics

__all__ = ["COST_TERMS", "Objective", "load_objective"]

#: The terms of the cost and the metric each one reads.
COST_TERMS = ("iae", "overshoot_pct", "sd_gap_deg", "settling_time_s", "control_effort")


class Weights(BaseModel):
    """Weights of the cost terms (each >= 0)."""

    model_config = ConfigDict(extra="forbid")

    iae: float = Field(1.0, ge=0)
    overshoot_pct: float = Field(0.5, ge=0)
    sd_gap_deg: float = Field(5.0, ge=0)
    settling_time_s: float = Field(2.0, ge=0)
    control_effort: float = Field(0.001, ge=0)


class Objective(BaseModel):
    """A tuning objective: weights and the caps that keep costs finite.

    Examples
    --------
    >>> from gripper_env.simulation import simulate
    >>> from gripper_env.metrics import compute_metrics
    >>> objective = load_objective()
    >>> traj = simulate("test2", "step", gains=[(1.0, 9.0, -0.001)], disturbance="ideal")
    >>> float(objective.cost(compute_metrics(traj))[0]) < 100
    True
    """

    model_config = ConfigDict(extra="forbid")

    name: str = "default"
    weights: Weights = Weights()
    max_cost: float = Field(1000.0, gt=0)
    unstable_cost: float = Field(10000.0, gt=0)

    @model_validator(mode="after")
    def _order(self) -> Objective:
        if self.unstable_cost <= self.max_cost:
            raise ValueError("unstable_cost must exceed max_cost so a diverged run is the worst")
        return self

    def terms(self, metrics: Metrics, duration_s: float | None = None) -> dict[str, np.ndarray]:
        """The unweighted terms per run (finite for stable runs)."""
        settle = np.stack([metrics.grip["settling_time_s"], metrics.ungrip["settling_time_s"]])
        cap = duration_s if duration_s is not None else 1e3
        settle = np.where(np.isfinite(settle), settle, cap).mean(axis=0)
        overshoot = np.maximum(metrics.grip["overshoot_pct"], metrics.ungrip["overshoot_pct"])
        return {
            "iae": metrics.run["iae"],
            "overshoot_pct": np.where(np.isfinite(overshoot), overshoot, 0.0),
            "sd_gap_deg": metrics.run["sd_gap_deg"],
            "settling_time_s": settle,
            "control_effort": metrics.run["control_effort"],
        }

    def cost(self, metrics: Metrics, duration_s: float | None = None) -> np.ndarray:
        """Cost per run (shape (B,)), finite: ``unstable_cost`` for diverged runs."""
        terms = self.terms(metrics, duration_s)
        w = self.weights.model_dump()
        stable = np.asarray(metrics.stable, dtype=bool)
        total = np.zeros(len(stable))
        for name in COST_TERMS:
            value = np.where(stable, terms[name], 0.0)
            total += w[name] * np.where(np.isfinite(value), value, self.max_cost)
        total = np.minimum(total, self.max_cost)
        return np.where(stable, total, self.unstable_cost)


def load_objective(
    objective: str | os.PathLike[str] | Mapping[str, Any] | Objective | None = None,
) -> Objective:
    """The default objective (``configs/objective.yaml``), another file, or a dict."""
    if isinstance(objective, Objective):
        return objective
    if isinstance(objective, Mapping):
        return validate(Objective, dict(objective), "objective dict")
    path = CONFIG_DIR / "objective.yaml" if objective is None else objective
    return validate(Objective, load_yaml(path), str(path))

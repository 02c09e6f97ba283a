"""Tuner and evaluation settings: ``configs/tuners/*.yaml``, validated on load.

Each file has a pydantic schema here; a problem is a :class:`~gripper_env.io.config.ConfigError`
that names the file and the key. A command-line ``--config PATH`` replaces the default file.
"""

from __future__ import annotations

import math
import os
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from gripper_env.io.config import ConfigError, config_file, load_yaml, validate
from gripper_env.model.pid import PIDOptions

__all__ = [
    "MAX_SEARCH_SEEDS",
    "MAX_TRIALS",
    "ClassicalSettings",
    "EvaluationSettings",
    "OptunaSettings",
    "ParamRange",
    "SeedRange",
    "check_disjoint",
    "load_settings",
]

_STRICT = ConfigDict(extra="forbid")


class SeedRange(BaseModel):
    """A block of consecutive disturbance seeds ``start, start + 1, ..., start + count - 1``."""

    model_config = _STRICT

    start: int = Field(0, ge=0)
    count: int = Field(4, ge=1, le=10000)

    def seeds(self) -> np.ndarray:
        """The seeds as an int64 array."""
        return np.arange(self.start, self.start + self.count, dtype=np.int64)


class PIDSettings(BaseModel):
    """PID structure used for every evaluation (see :class:`gripper_env.model.pid.PIDOptions`)."""

    model_config = _STRICT

    N: float = Field(100.0, gt=0, lt=2000.0)
    output_limits_deg: tuple[float, float] = (0.0, 180.0)
    anti_windup: Literal["none", "clamping", "back-calculation"] = "clamping"
    kb: float = 1.0
    derivative_on: Literal["error", "measurement"] = "error"

    @field_validator("output_limits_deg")
    @classmethod
    def _limits(cls, v: tuple[float, float]) -> tuple[float, float]:
        if math.isnan(v[0]) or math.isnan(v[1]) or v[0] >= v[1]:
            raise ValueError(f"must be [min, max] with min < max, got {list(v)}")
        return v

    def options(self, sign: int = 1) -> PIDOptions:
        """The :class:`PIDOptions` with error sign ``sign``."""
        return PIDOptions(
            output_limits=(self.output_limits_deg[0], self.output_limits_deg[1]),
            anti_windup=self.anti_windup,
            kb=self.kb,
            derivative_on=self.derivative_on,
            sign=sign,
        )


class EvaluationSettings(BaseModel):
    """``configs/tuners/evaluation.yaml``: PID structure and held-out seeds."""

    model_config = _STRICT

    pid: PIDSettings = PIDSettings()
    seeds: SeedRange = SeedRange(start=100000, count=10)
    randomize: bool = True
    limits_on_ideal: bool = False

    def options(self, sign: int = 1) -> tuple[PIDOptions, PIDOptions]:
        """PID options on the ``(ideal, actual)`` models for error sign ``sign``: the actual
        gripper's PID has the grasp mode (:class:`gripper_env.model.pid.GraspOptions`, on by
        default; it changes nothing while the jaw moves freely), the ideal model is Simulink's
        PID block."""
        actual = self.pid.options(sign)
        if self.limits_on_ideal:
            return actual, actual
        # the paper's Simulink model: no output limits and no grasp mode (nothing to grasp)
        ideal = PIDOptions(
            anti_windup=actual.anti_windup,
            kb=actual.kb,
            derivative_on=actual.derivative_on,
            sign=sign,
            grasp=None,
        )
        return ideal, actual


class ParamRange(BaseModel):
    """Search range of one gain.

    ``linear``: uniform in ``[low, high]``; ``log``: log-uniform in ``[low, high]`` (``low > 0``);
    ``symlog``: either sign with magnitude log-uniform in ``[low, high]``, searched as one float
    ``u`` in ``[-1, 1]`` with ``value = sign(u) * low * (high / low) ** |u|``.
    """

    model_config = _STRICT

    scale: Literal["linear", "log", "symlog"] = "linear"
    low: float
    high: float

    @model_validator(mode="after")
    def _order(self) -> ParamRange:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(f"need finite low < high, got [{self.low}, {self.high}]")
        if self.scale in ("log", "symlog") and self.low <= 0:
            raise ValueError(f"scale {self.scale!r} needs low > 0, got {self.low}")
        return self

    def decode(self, u: float) -> float:
        """The gain for a searched value (identity except for ``symlog``)."""
        if self.scale != "symlog":
            return float(u)
        mag = self.low * (self.high / self.low) ** abs(u)
        return float(math.copysign(mag, u))


class SearchSettings(BaseModel):
    """Ranges of P, I, D and N; ``units: plant`` scales P, I and D by the plant
    (:mod:`tuners.search_space`)."""

    model_config = _STRICT

    units: Literal["plant", "absolute"] = "plant"
    P: ParamRange
    I: ParamRange  # noqa: E741 - Simulink's name
    D: ParamRange
    N: ParamRange = ParamRange(scale="log", low=10.0, high=1000.0)

    @field_validator("N")
    @classmethod
    def _n_range(cls, v: ParamRange) -> ParamRange:
        if v.low <= 0 or v.high >= 2000.0:
            raise ValueError("N must stay in (0, 2000) 1/s so that N*dt < 2 at dt = 1 ms")
        return v


MOTerm = Literal[
    "iae",
    "overshoot_pct",
    "settling_time_s",
    "stall_s",
    "saturation_s",
    "servo_effort_deg",
    "sd_gap_deg",
    "control_effort",
]


class MultiObjective(BaseModel):
    model_config = _STRICT

    objectives: list[MOTerm] = ["iae", "overshoot_pct", "servo_effort_deg"]

    @field_validator("objectives")
    @classmethod
    def _two(cls, v: list[str]) -> list[str]:
        if len(v) < 2 or len(set(v)) != len(v):
            raise ValueError("need at least two different objectives")
        return v


#: Most finished trials a study may be asked for (TPE's cost per trial grows with the trials).
MAX_TRIALS = 100_000
#: Most independent studies (search seeds) one run may make.
MAX_SEARCH_SEEDS = 100


class OptunaSettings(BaseModel):
    """``configs/tuners/optuna.yaml`` (see the comments there)."""

    model_config = _STRICT

    trials: int = Field(200, ge=1, le=MAX_TRIALS)
    first_trials: int = Field(800, ge=1, le=MAX_TRIALS)
    first_search_seeds: int = Field(3, ge=1, le=MAX_SEARCH_SEEDS)
    batch_size: int = Field(16, ge=1, le=1024)
    tuning_seeds: SeedRange = SeedRange()
    search_seeds: int = Field(3, ge=1, le=MAX_SEARCH_SEEDS)
    sampler: Literal["tpe", "cmaes", "random"] = "tpe"
    n_startup_trials: int = Field(16, ge=0)
    local_fraction: float = Field(0.6, ge=0.0, lt=1.0)
    warm_start: bool = True
    tune_N: bool = False
    search: SearchSettings
    multi_objective: MultiObjective = MultiObjective()
    heartbeat_interval_s: int = Field(5, ge=1)
    heartbeat_grace_s: int = Field(30, ge=1)

    @model_validator(mode="after")
    def _grace(self) -> OptunaSettings:
        if self.heartbeat_grace_s <= self.heartbeat_interval_s:
            raise ValueError("heartbeat_grace_s must exceed heartbeat_interval_s")
        return self


ClassicalMethod = Literal["simc", "lambda", "amigo-pi", "amigo-pid", "migo", "pidtune"]


class ClassicalSettings(BaseModel):
    """``configs/tuners/classical.yaml`` (see the comments there)."""

    model_config = _STRICT

    method: ClassicalMethod = "amigo-pi"
    window_s: float = Field(9.0, gt=0)
    extra_dead_time_s: float = Field(0.0, ge=0)
    tau_c_factor: float = Field(1.0, gt=0)
    tau_c_min_s: float = Field(0.0, ge=0)
    theta_factor: float = Field(1.0, gt=0)
    migo_ms: float = Field(1.4, gt=1.0)
    pidtune_pm_deg: float = Field(60.0, gt=0.0, lt=90.0)
    pidtune_wc_hz: float = Field(0.0, ge=0.0)


_DEFAULT_FILES = {
    EvaluationSettings: "evaluation.yaml",
    OptunaSettings: "optuna.yaml",
    ClassicalSettings: "classical.yaml",
}


def load_settings(kind: type[BaseModel], path: str | os.PathLike[str] | None = None):
    """Load and validate one settings file (default ``configs/tuners/<kind>.yaml``).

    Raises
    ------
    ConfigError
        Missing file, invalid YAML, unknown key or value out of range (names file and key).
    """
    p = config_file("tuners", _DEFAULT_FILES[kind]) if path is None else path
    return validate(kind, load_yaml(p), str(p))


def check_disjoint(tuning: SeedRange, held_out: SeedRange) -> None:
    """Refuse tuning seeds that overlap the held-out evaluation seeds."""
    if tuning.start < held_out.start + held_out.count and held_out.start < (
        tuning.start + tuning.count
    ):
        raise ConfigError(
            f"tuning seeds [{tuning.start}, {tuning.start + tuning.count}) overlap the held-out "
            f"evaluation seeds [{held_out.start}, {held_out.start + held_out.count})"
        )

"""``configs/benchmark.yaml``: the plants, the rows (tuners from the registry), the references."""

from __future__ import annotations

import os
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from gripper_env.io.config import ConfigError, config_file, load_yaml, validate
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference

__all__ = ["BenchmarkSettings", "load_benchmark_settings"]

_STRICT = ConfigDict(extra="forbid")


class ReferencesPart(BaseModel):
    """The unranked reference rows: the limit (a linear program) and the oracle (an MPC)."""

    model_config = _STRICT
    limit: bool = True
    oracle: bool = True
    oracle_seeds: int | None = Field(None, ge=1)  # default: every held-out seed


class StressPart(BaseModel):
    """Extra held-out seeds of one plant on which every headline candidate is run again."""

    model_config = _STRICT
    plant: str = "test2"
    start: int = Field(300000, ge=0)
    count: int = Field(50, ge=0, le=10000)


class StopsMovedPart(BaseModel):
    """The verdict with both stops ``shift_deg`` further out; the robust rows named in
    ``retune`` are tuned again under the moved stops."""

    model_config = _STRICT
    shift_deg: float = Field(3.0, ge=0.0)
    retune: list[str] = []


class QuickPart(BaseModel):
    """``--quick``: fewer plants, every tuner at its quick budget, no robust rows."""

    model_config = _STRICT
    plants: list[str] = ["test1", "test2"]
    robust: bool = False
    rows: list[str] | None = None  # the rows of the quick run (default: every per-plant row)
    limit: bool = True
    oracle_seeds: int = Field(2, ge=1)
    pareto_points: int = Field(3, ge=0)
    stress_seeds: int = Field(5, ge=0)


class BenchmarkSettings(BaseModel):
    """The benchmark (see the comments in ``configs/benchmark.yaml``)."""

    model_config = _STRICT
    plants: list[str] = ["test1", "test2", "test3", "test4"]
    robust_plants: list[str] = ["test2", "test3", "test4"]
    disturbance: str = "actual"
    grip_scenario: str = "grip-object"
    profile: str = "step"
    seed: int = 0
    tuners: list[dict[str, Any]]
    references: ReferencesPart = ReferencesPart()
    pareto_ms: list[float] = [1.2, 1.3, 1.4, 1.5, 1.6, 1.8, 2.0, 2.4]
    stress: StressPart = StressPart()
    stops_moved: StopsMovedPart = StopsMovedPart()
    quick: QuickPart = QuickPart()

    @field_validator("tuners")
    @classmethod
    def _rows(cls, v: list[dict[str, Any]]) -> list[dict[str, Any]]:
        if not v:
            raise ValueError("list at least one tuner")
        for entry in v:
            if not isinstance(entry, dict) or "family" not in entry:
                raise ValueError(f"each tuner needs a 'family', got {entry!r}")
        return v


def load_benchmark_settings(path: str | os.PathLike[str] | None = None) -> BenchmarkSettings:
    """Load, validate and check the benchmark's settings: every plant, preset, profile and tuner
    named must exist (one-line errors that name the file)."""
    from tuners.registry import make_tuner

    p = config_file("benchmark.yaml") if path is None else path
    bench = validate(BenchmarkSettings, load_yaml(p), str(p))
    for plant in {*bench.plants, *bench.quick.plants, *bench.robust_plants}:
        try:
            load_plant(plant)
        except ConfigError as exc:
            raise ConfigError(f"{p}: {exc}") from None
    load_disturbance(bench.disturbance)
    load_disturbance(bench.grip_scenario)
    load_reference(bench.profile)
    names = set()
    for entry in bench.tuners:
        tuner = make_tuner(entry, str(p))
        if tuner.name in names:
            raise ConfigError(f"{p}: two rows are named {tuner.name!r}")
        if tuner.plants and list(tuner.plants) != bench.robust_plants:
            raise ConfigError(f"{p}: row {tuner.name} is tuned on {list(tuner.plants)}; robust "
                              f"rows are tuned on robust_plants {bench.robust_plants}")  # fmt: skip
        names.add(tuner.name)
    for entry in bench.tuners:
        for need in make_tuner(entry, str(p)).__dict__.get("requires", ()):
            if need not in names:
                raise ConfigError(f"{p}: row {entry!r} builds on {need!r}, which is not a row")
    for name in bench.stops_moved.retune:
        if name not in names:
            raise ConfigError(f"{p}: stops_moved.retune names {name!r}, which is not a row")
    if bench.stress.plant not in bench.plants:
        raise ConfigError(f"{p}: stress.plant {bench.stress.plant!r} is not one of the plants")
    return bench

"""The paper's validation stage 1 (Table 2, Figure 9): identified models against the actual gripper.

Every identified model and the actual gripper are driven by one validation profile
(:func:`gripper_env.sysid.experiments.validation_reference`); each model's response is compared
with the actual one by the paper's criterion, the sample SD and the gap between SDs, and by
MATLAB's fit %, which also sees a lag or an offset that leaves the spread unchanged.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env import paper
from gripper_env.evaluation.metrics import fit_percent, sample_sd
from gripper_env.model.plants import Plant, load_plant
from gripper_env.sim import simulate
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.experiments import IdentifiedExperiment
from gripper_env.sysid.logfile import read_log

__all__ = ["Validation", "ValidationRow", "validate_models"]


@dataclass(frozen=True)
class ValidationRow:
    """One model's direct response against the actual one.

    Attributes
    ----------
    name : str
        ``"test1"`` ...
    sd_deg : float
        Sample SD of the model's response over the run (deg, ``ddof=1``).
    sd_gap_deg : float
        ``SD_actual - SD_model`` (deg), the paper's Table-2 column (signed).
    fit_pct : float
        MATLAB ``compare`` fit (%) of the model's response to the actual measured one.
    fit_pct_plant : float
        The same for the model used as a plant file (absolute angles from quasi-rest at the
        first angle, the ``ideal`` preset); NaN when not computed.
    stable : bool
        All poles in the open left half plane.
    """

    name: str
    sd_deg: float
    sd_gap_deg: float
    fit_pct: float
    fit_pct_plant: float = float("nan")
    stable: bool = True

    @property
    def abs_sd_gap_deg(self) -> float:
        """``|SD_actual - SD_model|`` (deg)."""
        return abs(self.sd_gap_deg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "sd_deg": self.sd_deg,
            "sd_gap_deg": self.sd_gap_deg,
            "abs_sd_gap_deg": self.abs_sd_gap_deg,
            "fit_pct": self.fit_pct,
            "fit_pct_plant": None if np.isnan(self.fit_pct_plant) else self.fit_pct_plant,
            "stable": self.stable,
        }


@dataclass(frozen=True)
class Validation:
    """The direct-response validation (the paper's Table 2, Figure 9).

    Attributes
    ----------
    log_path : Path
        CSV record of the actual gripper's run.
    t_s, desired_deg, actual_deg : ndarray
        That record (uniform grid).
    responses : dict of str to ndarray
        Each identified model's response (as identified: at rest at its operating point).
    rows : tuple of ValidationRow
        Our identified models, in Table-1 order.
    paper_rows : tuple of ValidationRow
        The paper's four transfer functions on the same run (absolute angles, ``ideal`` preset,
        as ``gripper_env.paper`` drives them).
    """

    log_path: Path
    t_s: np.ndarray = field(repr=False)
    desired_deg: np.ndarray = field(repr=False)
    actual_deg: np.ndarray = field(repr=False)
    responses: dict[str, np.ndarray] = field(repr=False)
    rows: tuple[ValidationRow, ...]
    paper_rows: tuple[ValidationRow, ...]

    @property
    def sd_actual_deg(self) -> float:
        """Sample SD of the actual measured response (deg)."""
        return float(sample_sd(self.actual_deg))

    @property
    def best_by_sd_gap(self) -> str:
        """The paper's choice: the model with the smallest ``|SD_actual - SD_model|``."""
        return min(self.rows, key=lambda r: r.abs_sd_gap_deg).name

    @property
    def best_by_fit(self) -> str:
        """The model whose response fits the actual one best (fit %)."""
        return max(self.rows, key=lambda r: r.fit_pct).name

    @property
    def criteria_agree(self) -> bool:
        """Whether the SD-gap and fit-% choices are the same model."""
        return self.best_by_sd_gap == self.best_by_fit

    def to_dict(self) -> dict[str, Any]:
        return {
            "log": str(self.log_path),
            "duration_s": float(self.t_s[-1] - self.t_s[0]),
            "sd_actual_deg": self.sd_actual_deg,
            "rows": [r.to_dict() for r in self.rows],
            "paper_rows": [r.to_dict() for r in self.paper_rows],
            "best_by_sd_gap": self.best_by_sd_gap,
            "best_by_fit": self.best_by_fit,
            "criteria_agree": self.criteria_agree,
        }


def _plant_response(plant: Plant, u: np.ndarray, dt_s: float) -> np.ndarray:
    if not np.isclose(plant.dt_s, dt_s):
        plant = dataclasses.replace(plant, dt_s=dt_s)
    return simulate(plant, u, gains=None, disturbance="ideal").y_true[0]


def _row(name: str, y_actual: np.ndarray, y_model: np.ndarray, **extra: Any) -> ValidationRow:
    sd = float(sample_sd(y_model))
    return ValidationRow(
        name=name,
        sd_deg=sd,
        sd_gap_deg=float(sample_sd(y_actual)) - sd,
        fit_pct=float(fit_percent(y_actual, y_model)),
        **extra,
    )


def validate_models(
    identified: Sequence[IdentifiedExperiment], log_path: str | os.PathLike[str]
) -> Validation:
    """Compare each identified model with the actual gripper's validation record.

    Each model is driven by the record's desired angle *as identified*: at rest at its
    operating point, ``y_op + G(s) (u - u_op)`` (:meth:`TFEstimate.simulate` with a zero initial
    state). The fit of the same model used as a plant file (absolute angles, as every other
    command uses it) is reported beside it, and so are the paper's transfer functions.

    Parameters
    ----------
    identified : sequence of IdentifiedExperiment
        The models.
    log_path : str or PathLike
        The actual gripper's validation record (CSV).
    """
    data = prepare_data(*read_log(log_path), offset="none")
    t, u, y, dt = data.t_s, data.u, data.y, data.dt_s
    responses: dict[str, np.ndarray] = {}
    rows = []
    for item in identified:
        est = item.estimate
        # the model on the validation grid (the log's interval may differ from the record's)
        est_v = dataclasses.replace(est, dt_s=dt)
        y_model = est_v.simulate(u, np.zeros_like(est.initial_state))
        responses[item.experiment.name] = y_model
        y_plant = _plant_response(item.plant(), u, dt)
        rows.append(
            _row(
                item.experiment.name,
                y,
                y_model,
                fit_pct_plant=float(fit_percent(y, y_plant)),
                stable=bool(est.stable),
            )
        )
    paper_rows = []
    for name in paper.PLANTS:
        y_paper = _plant_response(load_plant(name), u, dt)
        paper_rows.append(_row(name, y, y_paper, stable=load_plant(name).is_stable))
    return Validation(Path(log_path), t, u, y, responses, tuple(rows), tuple(paper_rows))

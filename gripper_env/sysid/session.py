"""An identification session as the paper ran it, and the actual gripper identified from it.

:func:`run_identification`:

1. records and identifies each Table-1 experiment (:mod:`gripper_env.sysid.experiments`);
2. records the direct-response validation run and compares every model with it, as the
   paper's validation stage 1 (:mod:`gripper_env.sysid.direct_response`): SD, SD gap, and
   fit % on that validation record -- the fit a model earns on data it was not estimated from;
3. identifies the actual gripper -- transfer function, friction, sensor, delay -- from one of the
   records with the simulation core (:mod:`gripper_env.sysid.greybox`), and scores that model on
   the validation record too.

:func:`save_plants` writes each model as a plant file; :func:`save_actual` writes the grey-box
result as a plant file and a disturbance preset, the pair ``tuners.optuna`` tunes on.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gripper_env.io.files import write_atomic
from gripper_env.model.references import Reference, load_reference
from gripper_env.sysid.direct_response import Validation, validate_models
from gripper_env.sysid.experiments import (
    EXPERIMENTS,
    SVF_LAMBDAS,
    VALIDATION_RUN,
    Experiment,
    IdentifiedExperiment,
    Recorder,
    validation_reference,
)
from gripper_env.sysid.experiments import identify_log as _identify_log
from gripper_env.sysid.greybox import ActualEstimate, identify_actual
from gripper_env.sysid.logfile import read_log
from gripper_env.sysid.orders import Record
from gripper_env.sysid.plant_file import plant_dict, plant_yaml
from gripper_env.sysid.preset_file import save_preset_yaml

__all__ = [
    "IdentificationRun",
    "greybox_experiment",
    "run_identification",
    "save_actual",
    "save_plants",
]


@dataclass(frozen=True)
class IdentificationRun:
    """A whole session.

    Attributes
    ----------
    experiments : tuple of IdentifiedExperiment
        In Table-1 order.
    validation : Validation
        Stage 1 (Table 2).
    actual : ActualEstimate or None
        The grey-box identification of the actual gripper (None if not run).
    actual_from : str
        Which experiment's record it came from.
    source : str
        What was recorded (the simulated gripper's description, or the device).
    """

    experiments: tuple[IdentifiedExperiment, ...]
    validation: Validation
    actual: ActualEstimate | None = None
    actual_from: str = ""
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "experiments": [e.to_dict() for e in self.experiments],
            "validation": self.validation.to_dict(),
            "actual": None if self.actual is None else self.actual.to_dict(),
            "actual_from": self.actual_from,
        }


def greybox_experiment(experiments: Sequence[Experiment]) -> Experiment:
    """The record the grey-box fit uses: the slowest slope (most stick-slip), else the first."""
    slopes = [e for e in experiments if e.profile.startswith("slope")]
    return (
        max(slopes, key=lambda e: int(e.profile.removeprefix("slope")))
        if slopes
        else (experiments[0])
    )


def run_identification(
    recorder: Recorder,
    log_dir: str | os.PathLike[str],
    experiments: Sequence[Experiment] = EXPERIMENTS,
    validation: Reference | None = None,
    source: str = "",
    progress: Callable[[str], None] | None = None,
    svf_lambdas: Sequence[float | None] = SVF_LAMBDAS,
    *,
    greybox: bool = True,
    base_preset: str = "actual",
) -> IdentificationRun:
    """Record and identify every experiment, validate them, and identify the actual gripper.

    Parameters
    ----------
    recorder : Recorder
        Runs a profile open loop and writes its CSV log.
    log_dir : str or PathLike
        Folder of the logs: ``<test>_<profile>.csv`` per experiment and ``validation.csv``.
    experiments : sequence of Experiment
        Which Table-1 experiments (default: all four).
    validation : Reference, optional
        Validation profile; default :func:`gripper_env.sysid.experiments.validation_reference`.
    source : str
        Description of what ``recorder`` records, kept in the result.
    progress : callable, optional
        Called with a short message after each step.
    svf_lambdas : sequence of float or None
        Starts of each identification (:func:`gripper_env.sysid.experiments.identify_log`).
    greybox : bool
        Also identify the actual gripper (:func:`gripper_env.sysid.greybox.identify_actual`)
        from :func:`greybox_experiment`'s record.
    base_preset : str
        The preset whose known blocks (command path, stops, ADC bits) the grey-box fit keeps.
    """
    if not experiments:
        raise ValueError("at least one experiment is needed")
    log_dir = Path(log_dir)
    say = progress or (lambda _msg: None)
    done = []
    for exp in experiments:
        ref = load_reference(exp.profile)
        path = recorder(ref, log_dir / f"{exp.label}.csv", exp.number - 1)
        item = _identify_log(path, exp, svf_lambdas=svf_lambdas)
        est = item.estimate
        say(f"{exp.name} ({exp.profile}): {est.paper_form()}, fit {est.fit_pct:.2f} %")
        done.append(item)
    ref = validation if validation is not None else validation_reference()
    val_path = recorder(ref, log_dir / "validation.csv", VALIDATION_RUN)
    val = validate_models(done, val_path)
    say(
        f"validation: SD actual {val.sd_actual_deg:.3f} deg; best by SD gap "
        f"{val.best_by_sd_gap}, best by fit {val.best_by_fit}"
    )
    actual, actual_from = None, ""
    if greybox:
        exp = greybox_experiment(experiments)
        item = done[list(experiments).index(exp)]
        t, u, y = read_log(val_path)
        actual = identify_actual(
            item.t_s,
            item.desired_deg,
            item.actual_deg,
            base=base_preset,
            validation=Record(t, u, y),
        )
        actual_from = exp.label
        f = actual.friction
        say(
            f"actual gripper from {exp.label}: S {f.S_deg:.3g} deg, J {f.J_deg:.3g} deg, noise "
            f"{actual.sensor.noise_std_deg:.3g} deg, delay {1e3 * actual.delay_s:.3g} ms, fit "
            f"{actual.validation['fit_pct']:.2f} % on the validation record"  # type: ignore[index]
        )
    return IdentificationRun(tuple(done), val, actual, actual_from, source)


def save_plants(
    run: IdentificationRun, folder: str | os.PathLike[str], source: str = ""
) -> list[Path]:
    """Write each identified model as a plant file ``ident_<test>_<profile>.yaml``, atomically.

    The files load with :func:`gripper_env.model.plants.load_plant` (by path) like the paper's
    plants.
    """
    out = []
    fits = {row.name: row.fit_pct for row in run.validation.rows}
    for item in run.experiments:
        name = f"ident_{item.experiment.label}"
        est = item.estimate
        description = (
            f"Identified by python -m tuners.sysid experiments from {item.experiment.name} "
            f"({item.experiment.description}){', ' + source if source else ''}: "
            f"{est.residuals.size} samples at {est.dt_s:g} s, fit {est.fit_pct:.2f} % on them "
            f"(initial state estimated), {fits[item.experiment.name]:.2f} % on the validation "
            f"record; input delay {1e3 * est.input_delay_s:.3g} ms; identified about the "
            f"operating point u_op={est.u_op:.4g} deg, y_op={est.y_op:.4g} deg."
        )
        doc = plant_dict(est, name, description)
        path = Path(folder) / f"{name}.yaml"
        out.append(write_atomic(path, plant_yaml(doc, est.input_delay_s)))
    return out


def save_actual(
    est: ActualEstimate,
    plant_path: str | os.PathLike[str] | None,
    preset_path: str | os.PathLike[str] | None,
    *,
    name: str | None = None,
    base_ref: str | None = "actual",
    source: str = "",
    command: str = "",
) -> list[Path]:
    """Write the grey-box result: the servo's transfer function as a plant file and the rest as
    a disturbance preset (either may be skipped with None); returns the paths written."""
    out = []
    if plant_path is not None:
        p = Path(plant_path)
        plant = est.plant(name or p.stem)
        description = (
            f"Servo dynamics identified with its friction, sensor and delay by "
            f"gripper_env.sysid.greybox from {source or 'a log'}; the whole model fits it at "
            f"{est.fit_pct:.2f} %. Use with the disturbance preset identified beside it."
        )
        doc = {
            "name": plant.name,
            "description": description,
            "num": list(plant.num),
            "den": list(plant.den),
            "fit_pct": round(est.fit_pct, 2),
            "dt_s": est.dt_s,
            "jaw_range_deg": list(plant.jaw_range_deg),
        }
        out.append(write_atomic(p, plant_yaml(doc)))
    if preset_path is not None:
        out.append(
            save_preset_yaml(
                est, preset_path, name, base_ref=base_ref, source=source, command=command
            )
        )
    return out

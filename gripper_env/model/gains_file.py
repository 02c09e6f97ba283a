"""The one gains file format (JSON), written by every tuner and read by ``tuners.manual`` and
``tuners.rig.deploy``.

``results/<plant>/<tuner>.json``, format ``gripper-gains`` version :data:`FORMAT_VERSION`:

.. code-block:: text

    format, format_version      "gripper-gains", 1
    plant, tuner, label         which plant, which tuner, a free label ("paper-tuned", ...)
    plant_model                 the plant's transfer function as tuned on: name, num, den, dt_s,
                                jaw_range_deg, fit_pct, source (so a plant tuned from the
                                user's own file is found again wherever the gains file goes)
    P, I, D, N                  Simulink parallel-form gains: deg/deg, 1/s, s, 1/s
    sign, sign_convention       +1 for e = r - y, -1 for e = y - r (the paper's hardware gains)
    limits                      output_deg [min, max], anti_windup, kb, derivative_on, grasp
                                (the PID's grasp mode: {squeeze_deg, push_deg, short_deg,
                                still_deg, dwell_s}, or null for none; a file without the key,
                                written before the mode, gets the default mode, which changes
                                nothing while the jaw moves freely)
    sample_time_s               PID sample time (s)
    evaluation                  profile, disturbance preset, held-out seeds, randomize, signal,
                                the output limits used on the ideal model
    metrics                     ideal {...}; actual {mean, std, ci95_low, ci95_high, n_seeds,
                                stable_fraction}; sim_to_real_gap {...}  (metric keys: grip and
                                ungrip {overshoot_pct, rise_time_s, settling_time_s,
                                steady_state_error_deg, ...}, sd_deg, sd_gap_deg, iae, ise, itae,
                                control_effort, servo_effort_deg, saturation_s, contact_s,
                                stall_s, force_proxy, stable, cost)
    robustness                  the loop as it runs, with the servo's command hold: stable,
                                max_pole_magnitude, gain_margin_db, phase_margin_deg, ms, mt,
                                refresh_period_s; loop_1ms {...} (the 1 ms loop alone);
                                constraints, meets_constraints (gripper_env.evaluation.stability)
    cross_model                 the gains on the other identifications: plants {name: {...}}
                                and the worst case (``tuners.evaluation.cross_model``)
    admission                   the admission rule on the held-out runs: constraints {name:
                                value, <= 0 met}, admitted, missed, binding, reason, measured,
                                limits (gripper_env.evaluation.admission)
    tuning                      what the tuner wants to record (trials, best cost, study, search
                                ranges, on_bound: gains within 2 % of a search bound, ...)
    provenance                  command, config, seed (the version, commit, date, machine and
                                wall time go to the run's sidecar ``<name>.provenance.json``,
                                :func:`gripper_env.io.files.write_provenance`: a rerun with
                                equal numbers leaves the gains file unchanged)

Infinite or undefined numbers (a run that never settles, an unstable run) are written as
``null``. Files are written atomically (:func:`gripper_env.io.files.write_json`), so a reader
never sees half a file.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gripper_env._version import __version__
from gripper_env.io.config import SHIPPED
from gripper_env.io.files import json_ready, read_format_json
from gripper_env.model.pid import GraspOptions, PIDGains, PIDOptions
from gripper_env.model.plants import Plant, PlantSpec, load_plant

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "GainsFile",
    "GainsFileError",
    "build_gains_file",
    "load_gains_file",
    "provenance",
]

FORMAT = "gripper-gains"
FORMAT_VERSION = 2
#: Versions this code reads (version 1 had the 1 ms loop's margins as "stability").
READABLE_VERSIONS = (1, 2)


class GainsFileError(ValueError):
    """A gains file is missing, malformed, or from an incompatible format version."""


def provenance(
    config: dict[str, Any] | None = None,
    seed: int | None = None,
    wall_time_s: float | None = None,
    command: str | None = None,
) -> dict[str, Any]:
    """What a result was made with: command line, configuration, seed, and how long it took
    (``wall_time_s``, which :func:`gripper_env.io.files.write_result_json` moves to the run's
    provenance sidecar with the commit, date and version,
    :func:`gripper_env.io.files.write_provenance`)."""
    if command is None:
        command = " ".join(["python", *sys.argv])
    return {
        "command": command,
        "config": config or {},
        "seed": seed,
        "wall_time_s": wall_time_s,
    }


def build_gains_file(
    *,
    plant: str,
    tuner: str,
    gains: PIDGains,
    options: PIDOptions,
    evaluation: Any,
    evaluation_settings: dict[str, Any],
    tuning: dict[str, Any] | None = None,
    prov: dict[str, Any] | None = None,
    label: str = "",
    sample_time_s: float = 1e-3,
    plant_model: Plant | None = None,
) -> dict[str, Any]:
    """Assemble the gains file's content (see the module docstring).

    Parameters
    ----------
    evaluation : object
        Metrics on the ideal and actual models: ``ideal``, ``actual``, ``sim_to_real_gap``,
        ``robustness`` and ``cross_model`` (a ``tuners.evaluation.Evaluation``).
    evaluation_settings : dict
        Profile, disturbance, seeds, randomize, signal, ideal-model limits.
    plant_model : Plant, optional
        The plant tuned on, recorded so that :meth:`GainsFile.plant_model` finds it again.
    """
    model = None
    if plant_model is not None:
        model = {
            "name": plant_model.name,
            "num": list(plant_model.num),
            "den": list(plant_model.den),
            "dt_s": plant_model.dt_s,
            "jaw_range_deg": list(plant_model.jaw_range_deg),
            "fit_pct": plant_model.fit_pct,
            "source": _portable_source(plant_model.source),
        }
    return json_ready(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "plant": plant,
            "plant_model": model,
            "tuner": tuner,
            "label": label,
            "P": gains.P,
            "I": gains.I,
            "D": gains.D,
            "N": gains.N,
            "sign": options.sign,
            "sign_convention": "e = r - y" if options.sign == 1 else "e = y - r",
            "limits": {
                "output_deg": list(options.output_limits),
                "anti_windup": options.anti_windup,
                "kb": options.kb,
                "derivative_on": options.derivative_on,
                "grasp": None if options.grasp is None else options.grasp.as_dict(),
            },
            "sample_time_s": sample_time_s,
            "evaluation": evaluation_settings,
            "metrics": {
                "ideal": evaluation.ideal,
                "actual": evaluation.actual,
                "sim_to_real_gap": evaluation.sim_to_real_gap,
            },
            "robustness": evaluation.robustness,
            "cross_model": evaluation.cross_model,
            "admission": getattr(evaluation, "admission", None) or {},
            "tuning": tuning or {},
            "provenance": prov or provenance(),
        }
    )


def _portable_source(source: str) -> str:
    """A shipped plant by its package path (``gripper_env.configs/plants/test2.yaml``), so that
    no machine's folder ends up in a committed gains file; a user's own file as given."""
    if not source:
        return source
    try:
        rel = Path(source).resolve().relative_to(Path(str(SHIPPED)).resolve())
    except (ValueError, OSError):
        return source
    return f"gripper_env.configs/{rel.as_posix()}"


@dataclass(frozen=True)
class GainsFile:
    """A loaded gains file: the controller it describes, and the raw content."""

    plant: str
    tuner: str
    gains: PIDGains
    options: PIDOptions
    content: dict[str, Any]

    def plant_model(self) -> Plant:
        """The plant these gains were tuned on: the transfer function the file records
        (``plant_model``), else the plant named ``plant`` (files written before it was recorded).

        Raises
        ------
        GainsFileError
            The file names no plant, or records a malformed one.
        gripper_env.io.config.ConfigError
            An older file names a plant that is not available here.
        """
        model = self.content.get("plant_model")
        if model is None:
            if not self.plant:
                raise GainsFileError("the gains file names no plant")
            return load_plant(self.plant)
        source = str(model.get("source") or "")
        fields = {k: v for k, v in model.items() if k != "source"}
        try:
            spec = PlantSpec(**fields)
        except (TypeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0]
            raise GainsFileError(f"the gains file's plant_model is malformed: {first}") from None
        return Plant.from_spec(spec, source=source)


def _number(content: dict[str, Any], key: str, source: str) -> float:
    value = content.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise GainsFileError(f"{source}: '{key}' must be a finite number, got {value!r}")
    return float(value)


def _grasp(limits: dict[str, Any]) -> GraspOptions | None:
    """``limits.grasp``: null for none, a mapping of :class:`GraspOptions`' fields (missing ones
    take its defaults), or no key (a file from before the mode: the default mode)."""
    if "grasp" not in limits:
        return GraspOptions()
    value = limits["grasp"]
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ValueError(f"limits.grasp must be null or a mapping, got {value!r}")
    known = set(GraspOptions().as_dict())
    unknown = sorted(set(value) - known)
    if unknown:
        raise ValueError(f"limits.grasp has unknown keys {unknown}; known: {sorted(known)}")
    return GraspOptions(**value)


def load_gains_file(path: str | os.PathLike[str]) -> GainsFile:
    """Read and check a gains file.

    Raises
    ------
    GainsFileError
        Missing or unreadable file, not JSON, not a gains file, a format version this code does
        not read, or gains/limits that are not valid numbers.
    """
    p = Path(path)
    content = read_format_json(p, FORMAT, "gains file", GainsFileError)
    version = content.get("format_version")
    if version not in READABLE_VERSIONS:
        raise GainsFileError(
            f"{p}: gains file format version {version!r} is not supported by this version "
            f"({__version__}), which reads versions {list(READABLE_VERSIONS)}; regenerate it "
            "with the tuner"
        )
    gains = [_number(content, k, str(p)) for k in ("P", "I", "D", "N")]
    limits = content.get("limits") or {}
    try:
        lo, hi = limits.get("output_deg", [None, None])
        options = PIDOptions(
            output_limits=(
                -math.inf if lo is None else float(lo),
                math.inf if hi is None else float(hi),
            ),
            anti_windup=limits.get("anti_windup", "clamping"),
            kb=float(limits.get("kb", 1.0)),
            derivative_on=limits.get("derivative_on", "error"),
            sign=content.get("sign", 1),
            grasp=_grasp(limits),
        )
        pid_gains = PIDGains(*gains)
    except (TypeError, ValueError) as exc:
        raise GainsFileError(f"{p}: {exc}") from None
    return GainsFile(
        plant=str(content.get("plant", "")),
        tuner=str(content.get("tuner", "")),
        gains=pid_gains,
        options=options,
        content=content,
    )

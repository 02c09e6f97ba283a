"""Writing an identified model as a plant file (the format of ``configs/plants/*.yaml``).

Keys, exactly those of the plant schema (``gripper_env.model.plants.PlantSpec``): ``name``,
``description``, ``num`` and ``den`` (highest power of ``s`` first), ``fit_pct``, ``dt_s`` (the
physics step, not the data's sample interval) and ``jaw_range_deg``.

A plant file holds the transfer function only. An identified input delay is written in its
description and in a comment at its top; the simulation core applies dead time through a
disturbance preset's ``sensor.delay_s`` (``python -m tuners.sysid greybox`` writes one).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from gripper_env.io.files import write_atomic
from gripper_env.sysid.tfest import TFEstimate

__all__ = ["plant_dict", "plant_yaml", "save_plant_yaml"]


def plant_dict(
    estimate: TFEstimate,
    name: str,
    description: str | None = None,
    *,
    dt_s: float = 0.001,
    jaw_range_deg: tuple[float, float] = (21.0, 92.0),
) -> dict[str, Any]:
    """The plant-file mapping for ``estimate`` (plain Python types, ready for YAML).

    Parameters
    ----------
    estimate : TFEstimate
        Result of :func:`gripper_env.sysid.tfest`.
    name : str
        Plant name (the file stem by convention).
    description : str, optional
        Free text; by default a summary of how the model was identified.
    dt_s : float
        Physics step of the simulation (s).
    jaw_range_deg : (float, float)
        Closed and open jaw limits (deg).
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError("name must be a non-empty string")
    lo, hi = (float(v) for v in jaw_range_deg)
    if not lo < hi:
        raise ValueError(
            f"jaw_range_deg must be [closed_deg, open_deg] with closed < open, got {[lo, hi]}"
        )
    if not dt_s > 0:
        raise ValueError(f"dt_s must be positive, got {dt_s}")
    if description is None:
        val = estimate.validation
        fits = (
            f"fit {val.fit_pct:.2f} % on validation data ({val.source}), "
            if val is not None
            else ""
        )
        description = (
            f"Identified with gripper_env.sysid.tfest (SRIVC start, output-error refinement): "
            f"{estimate.residuals.size} samples at {estimate.dt_s:g} s, {fits}fit "
            f"{estimate.fit_pct:.2f} % on the estimation data (initial state estimated), "
            f"{estimate.fit_pct_rest:.2f} % from rest; input delay "
            f"{1e3 * estimate.input_delay_s:.3g} ms. The model maps deviations from the "
            f"operating point (offset={estimate.offset!r}, u_op={estimate.u_op:.4g} deg, "
            f"y_op={estimate.y_op:.4g} deg)."
        )
    return {
        "name": name,
        "description": description,
        "num": [float(c) for c in estimate.num],
        "den": [float(c) for c in estimate.den],
        "fit_pct": round(float(estimate.headline_fit_pct), 2),
        "dt_s": float(dt_s),
        "jaw_range_deg": [lo, hi],
    }


def save_plant_yaml(
    estimate: TFEstimate,
    path: str | os.PathLike[str],
    name: str | None = None,
    description: str | None = None,
    *,
    dt_s: float = 0.001,
    jaw_range_deg: tuple[float, float] = (21.0, 92.0),
) -> Path:
    """Write ``estimate`` as a plant YAML file and return its path.

    ``name`` defaults to the file stem. Other parameters as :func:`plant_dict`.
    """
    p = Path(path)
    doc = plant_dict(
        estimate,
        name if name is not None else p.stem,
        description,
        dt_s=dt_s,
        jaw_range_deg=jaw_range_deg,
    )
    return write_atomic(p, plant_yaml(doc, estimate.input_delay_s))


def plant_yaml(doc: dict[str, Any], input_delay_s: float = 0.0) -> str:
    """YAML text of a plant-file mapping, with a comment line for an input delay."""
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    if input_delay_s > 0:
        text = (
            f"# input delay {1e3 * input_delay_s:.3g} ms: not a plant-file key; the core "
            "simulates it as a disturbance preset's sensor.delay_s\n" + text
        )
    return text

"""Writing an identified actual gripper as a disturbance preset (``configs/disturbances`` format).

The preset ``extends`` the base preset the identification kept its known blocks from (command
path, stops, ADC bits), and sets what was identified: friction (model, ``S``, ``J``), sensor noise,
ADC range and delay, plus per-episode randomisation ranges around them (the ranges consistent
with the data, at least +/- 20 %). Comments at the top say where it came from and what the data
could not tell. ``python -m tuners.optuna --plant mine.yaml --disturbance mine.yaml`` then tunes
on the user's own gripper.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from gripper_env.io.files import write_atomic
from gripper_env.model.disturbances import load_disturbance
from gripper_env.sysid.greybox import ActualEstimate

__all__ = ["preset_dict", "preset_yaml", "save_preset_yaml"]


def preset_dict(
    est: ActualEstimate, name: str, *, base_ref: str | None = None, source: str = ""
) -> dict[str, Any]:
    """The preset mapping (plain Python types).

    Parameters
    ----------
    est : ActualEstimate
        Result of :func:`gripper_env.sysid.greybox.identify_actual`.
    name : str
        Preset name (the file stem by convention).
    base_ref : str, optional
        How to refer to the base preset in ``extends`` (its name, or a path); without one the
        preset is written out whole.
    source : str
        The log it was identified from, for the description.
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError("name must be a non-empty string")
    f, s = est.friction, est.sensor
    description = (
        f"Identified from {source or 'a log'} by gripper_env.sysid.greybox: friction "
        f"{f.model} S={f.S_deg:.3g} deg J={f.J_deg:.3g} deg, noise {s.noise_std_deg:.3g} deg, "
        f"delay {1e3 * est.delay_s:.3g} ms; the model fits the log at {est.fit_pct:.2f} % "
        f"(residual {est.residual_rms_deg:.3g} deg RMS)."
    )
    overrides = est.preset_overrides()
    randomize = {k: [lo, hi] for k, (lo, hi) in est.randomize().items()}
    if base_ref is not None:
        return {
            "name": name,
            "description": description,
            "extends": base_ref,
            **overrides,
            "randomize": randomize,
        }
    full = est.disturbance(name, description).model_dump(mode="json")
    full["randomize"] = {**full.get("randomize", {}), **randomize}
    return full


def preset_yaml(est: ActualEstimate, doc: dict[str, Any], command: str = "") -> str:
    """YAML text of a preset mapping, with comments on what the data could and could not tell."""
    f = est.friction
    ok = f.identified()
    lines = [
        f"# Written by {command or 'gripper_env.sysid.greybox'} "
        f"({est.n_samples} samples at {est.dt_s:g} s).",
        f"# Friction consistent with the log: S {f.S_range_deg[0]:g}..{f.S_range_deg[1]:g} deg"
        f"{'' if ok['S_deg'] else ' (not pinned down by this log)'}, J "
        f"{f.J_range_deg[0]:g}..{f.J_range_deg[1]:g} deg"
        f"{'' if ok['J_deg'] else ' (not pinned down by this log)'}.",
        f"# Sensor offset (measured minus model) {est.offset_deg:+.3g} deg: the core has no "
        "sensor bias, so it is not in the preset.",
    ]
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    return "\n".join(lines) + "\n" + text


def save_preset_yaml(
    est: ActualEstimate,
    path: str | os.PathLike[str],
    name: str | None = None,
    *,
    base_ref: str | None = None,
    source: str = "",
    command: str = "",
) -> Path:
    """Write the preset, check that it loads, and return its path (``name``: the file stem)."""
    p = Path(path)
    doc = preset_dict(est, name if name is not None else p.stem, base_ref=base_ref, source=source)
    write_atomic(p, preset_yaml(est, doc, command))
    load_disturbance(p)  # a preset that does not load is a bug here, not the user's problem
    return p

"""Loading and validating configuration files (YAML) with errors that name the file and the key.

Configuration is data: plants, disturbance presets, tuner and benchmark settings. The files that
ship with the project live in the top-level ``configs/`` folder of the source tree, installed as
the package ``gripper_env.configs`` and read through :mod:`importlib.resources`, so a wheel
finds them wherever it is installed (:data:`SHIPPED`).

A name (``"test2"``, ``"mine"``) is looked up first in the folder the ``GRIPPER_CONFIG_DIR``
environment variable names, if it is set (same layout: ``plants/``, ``disturbances/``,
``tuners/``, ``objective.yaml``, ``benchmark.yaml``; any of them may be missing), then in the
shipped configurations. A path (``my/plant.yaml``) is read as it is. Every file is validated
once, on load, by a pydantic model; a problem is reported as a :class:`ConfigError` that names
the file and the offending key.
"""

from __future__ import annotations

import os
from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

__all__ = [
    "CONFIG_DIR",
    "SHIPPED",
    "ConfigError",
    "available",
    "config_file",
    "find_config",
    "load_yaml",
    "validate",
]


def _shipped() -> Traversable:
    try:
        return files("gripper_env.configs")
    except ModuleNotFoundError:
        # a source tree used without installing it (PYTHONPATH=.), or an editable install made
        # before configs/ became a package: the folder beside the package
        return Path(__file__).resolve().parent.parent / "configs"


#: The configurations shipped in the package (``gripper_env.configs``).
SHIPPED: Traversable = _shipped()
#: Where names are looked up first: the folder in ``GRIPPER_CONFIG_DIR``, else :data:`SHIPPED`.
CONFIG_DIR: Traversable = (
    Path(os.environ["GRIPPER_CONFIG_DIR"]) if os.environ.get("GRIPPER_CONFIG_DIR") else SHIPPED
)

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration file or value is missing, malformed or out of range."""


def load_yaml(path: str | os.PathLike[str] | Traversable) -> dict[str, Any]:
    """Read a YAML mapping from ``path`` (a file path, or a file of :data:`CONFIG_DIR`).

    Raises
    ------
    ConfigError
        If the file does not exist, is not valid YAML, or does not hold a mapping.
    """
    p = path if isinstance(path, Traversable) else Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such configuration file")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping of keys to values, got {type(data).__name__}")
    return data


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Validate ``data`` against ``model``; on failure raise one :class:`ConfigError` per problem.

    Parameters
    ----------
    model : pydantic model class
        The schema.
    data : dict
        The raw mapping (from YAML, JSON or a keyword argument).
    source : str
        Where the data came from (a file path or a description), used in the message.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            key = ".".join(str(part) for part in err["loc"]) or "<top level>"
            msg = err["msg"].removeprefix("Value error, ")
            problems.append(f"key '{key}': {msg}")
        raise ConfigError(f"{source}: " + "; ".join(problems)) from None


def _roots() -> list[Traversable]:
    """Folders searched for a name, in order (read at call time: tests may move CONFIG_DIR)."""
    return [CONFIG_DIR] if CONFIG_DIR == SHIPPED else [CONFIG_DIR, SHIPPED]


def config_file(*parts: str) -> Traversable:
    """A file of the configuration tree, e.g. ``config_file("tuners", "optuna.yaml")``: the first
    of :data:`CONFIG_DIR` and :data:`SHIPPED` that has it."""
    for root in _roots():
        if root.joinpath(*parts).is_file():
            return root.joinpath(*parts)
    return CONFIG_DIR.joinpath(*parts)  # missing: the error names where it was expected


def available(kind: str) -> list[str]:
    """Names of the configuration files of one kind (``"plants"``, ``"disturbances"``, ...)."""
    names: set[str] = set()
    for root in _roots():
        folder = root / kind
        if folder.is_dir():
            names.update(
                f.name[: -len(".yaml")] for f in folder.iterdir() if f.name.endswith(".yaml")
            )
    return sorted(names)


def find_config(kind: str, name_or_path: str | os.PathLike[str]) -> Traversable:
    """Resolve a configuration by name (``<kind>/<name>.yaml``, see the module docstring) or by
    path.

    Raises
    ------
    ConfigError
        If neither a file of that path nor a configuration of that name exists; the message lists
        the available names.
    """
    text = os.fspath(name_or_path)
    candidate = Path(text)
    if candidate.suffix in (".yaml", ".yml") or os.sep in text or "/" in text:
        if candidate.is_file():
            return candidate
        raise ConfigError(f"{kind[:-1]} file {text!r} does not exist")
    for root in _roots():
        named = root / kind / f"{text}.yaml"
        if named.is_file():
            return named
    names = ", ".join(available(kind)) or "(none)"
    raise ConfigError(f"unknown {kind[:-1]} {text!r}; available: {names}")

"""Loading and validating configuration files (YAML) with errors that name the file and the key.

Configuration is data in the top-level ``configs/`` folder (plants, disturbance presets, tuner and
benchmark settings). Every file is validated once, on load, by a pydantic model; a problem is
reported as a :class:`ConfigError` that names the file and the offending key.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

__all__ = ["CONFIG_DIR", "ConfigError", "available", "find_config", "load_yaml", "validate"]

#: Root of the configuration tree; override with the ``GRIPPER_CONFIG_DIR`` environment variable.
CONFIG_DIR = Path(
    os.environ.get("GRIPPER_CONFIG_DIR", Path(__file__).resolve().parent.parent / "configs")
)

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration file or value is missing, malformed or out of range."""


def load_yaml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a YAML mapping from ``path``.

    Raises
    ------
    ConfigError
        If the file does not exist, is not valid YAML, or does not hold a mapping.
    """
    p = Path(path)
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


def available(kind: str) -> list[str]:
    """Names of the configuration files of one kind (``"plants"``, ``"disturbances"``, ...)."""
    folder = CONFIG_DIR / kind
    return sorted(p.stem for p in folder.glob("*.yaml"))


def find_config(kind: str, name_or_path: str | os.PathLike[str]) -> Path:
    """Resolve a configuration by name (``configs/<kind>/<name>.yaml``) or by file path.

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
    named = CONFIG_DIR / kind / f"{text}.yaml"
    if named.is_file():
        return named
    names = ", ".join(available(kind)) or "(none)"
    raise ConfigError(f"unknown {kind[:-1]} {text!r}; available: {names}")

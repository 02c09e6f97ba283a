"""The registry of tuners: family name -> the class that implements :class:`tuners.interface.Tuner`.

The benchmark's configuration lists rows as ``{family: NAME, ...options}``; :func:`make_tuner`
builds each from this table. Families are named by ``"module:Class"`` so that the registry
imports nothing heavy (the RL tuners need the ``rl`` extra) until a row asks for it. A new tuner
is one module with one class; add its line here, or name it directly as
``family: package.module:Class`` in the configuration.
"""

from __future__ import annotations

import importlib
from typing import Any

from gripper_env.io.config import ConfigError
from tuners.interface import KINDS, Tuner

__all__ = ["FAMILIES", "make_tuner"]

FAMILIES: dict[str, str] = {
    "manual": "tuners.manual:ManualTuner",
    "classical": "tuners.classical.tuner:ClassicalTuner",
    "optuna": "tuners.optuna.tuner:OptunaTuner",
    "rl-tune": "tuners.rl.tuner:RLTuner",
    "rl-controller": "tuners.rl.tuner:RLControllerTuner",
}


def make_tuner(spec: dict[str, Any], where: str = "benchmark config") -> Tuner:
    """The tuner a configuration entry describes.

    Raises
    ------
    ConfigError
        Unknown family, a class that is not a :class:`Tuner`, or options it refuses (the message
        names ``where`` and the entry).
    """
    options = dict(spec)
    family = options.pop("family", None)
    if not isinstance(family, str):
        raise ConfigError(f"{where}: tuner entry {spec!r} has no 'family'")
    target = FAMILIES.get(family, family)
    if ":" not in target:
        raise ConfigError(
            f"{where}: unknown tuner family {family!r}; choose one of {', '.join(FAMILIES)} or "
            "name a class as 'package.module:Class'"
        )
    module_name, _, class_name = target.partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{where}: tuner family {family!r} ({target}): {exc}") from None
    try:
        tuner = cls(**options)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: tuner {spec!r}: {exc}") from None
    if not isinstance(tuner, Tuner) or tuner.kind not in KINDS:
        raise ConfigError(f"{where}: {target} is not a tuner (name, kind, plants, tune)")
    return tuner

"""The tuner interface: ``tune(inputs, budget, seed) -> Tuned``, like an Optuna ``BaseSampler``.

Every way of choosing a controller (the paper's gains, a textbook rule, a search, RL) is a
:class:`Tuner`: an object with a row ``name``, a ``kind`` and a :meth:`Tuner.tune` method that
takes the resolved inputs (plant, preset, profile, evaluation settings, objective), a
:class:`Budget` and a seed, and returns :class:`Tuned`: PID gains (or, for a learned controller,
a study of its policies) and the record of how they were found. The benchmark
(:mod:`tuners.benchmark`) builds its rows from a registry of tuners (:mod:`tuners.registry`),
evaluates every result through the one scoring path and never needs to know which family made
it; a new tuner is one module with one class, named in the registry.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from gripper_env.model.pid import PIDGains
from tuners import cli

__all__ = ["KINDS", "Budget", "Tuned", "Tuner"]

#: Row kinds: ``manual`` (given gains), ``baseline`` (a textbook rule, knob under the
#: constraints), ``reference`` (shown, never ranked: a rule at a fixed setting, command =
#: reference, the limit, the oracle), ``search`` (Optuna, the RL tuner), ``controller`` (a
#: learned controller).
KINDS = ("manual", "baseline", "reference", "search", "controller")


@dataclass(frozen=True)
class Budget:
    """How much a tuner may spend.

    Attributes
    ----------
    quick : bool
        The smoke-test budget (each tuner's ``quick`` settings).
    scale : float
        Multiplies the tuner's own budget (trials, episodes, steps).
    engine : str, optional
        Where independent runs (training seeds) go (:func:`tuners.engine.engine`).
    """

    quick: bool = False
    scale: float = 1.0
    engine: str | None = None


@dataclass
class Tuned:
    """What a tuner returns.

    Attributes
    ----------
    gains : PIDGains or None
        The PID gains, or ``None`` for a learned controller (``study`` then holds it).
    sign : int
        Error sign convention of the gains.
    tuning : dict
        How they were found (the gains file's ``tuning`` block): settings, seeds, spread,
        ``on_bound`` flags, the tuning cost.
    episodes : int
        Simulated 20 s episodes the tuning used.
    wall_s : float
        Wall time (s).
    label : str
        A short label for plots and files.
    study : dict, optional
        A learned controller's study (:func:`tuners.rl.controller.controller_study`).
    """

    gains: PIDGains | None
    sign: int = 1
    tuning: dict[str, Any] = field(default_factory=dict)
    episodes: int = 0
    wall_s: float = 0.0
    label: str = ""
    study: dict[str, Any] | None = None


@runtime_checkable
class Tuner(Protocol):
    """A way of choosing a controller.

    Attributes
    ----------
    name : str
        The row's (and gains file's) name, e.g. ``optuna-cmaes``.
    kind : str
        One of :data:`KINDS`.
    plants : tuple of str
        Empty: tuned on each plant in turn; else tuned once on these identifications (robust)
        and evaluated on each.
    """

    name: str
    kind: str
    plants: tuple[str, ...]

    def tune(self, inputs: cli.Inputs, budget: Budget, seed: int) -> Tuned:
        """Choose the controller for ``inputs`` (its plant, or ``plants``)."""
        ...

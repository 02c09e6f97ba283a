"""Textbook robust PID designs from the plant's model: the baselines every search must beat.

Usage::

    python -m tuners.classical --plant test2                      # default method: amigo-pi
    python -m tuners.classical --plant test2 --method migo
    python -m tuners.classical --plant test2 --method all         # every method, one table
    python -m tuners.classical --plant test2 --method simc --fixed   # tau_c = theta, unchanged

:mod:`~tuners.classical.rules` holds the rules (SIMC, lambda, AMIGO PI and PID, MIGO, a
pidtune-like loop shaping) for a given setting of each rule's robustness knob;
:mod:`~tuners.classical.constrained` sets that knob to its best value under the objective's
constraints, as an engineer using the rule would; :mod:`~tuners.classical.command` is the
command line.
"""

from typing import TYPE_CHECKING

from gripper_env._lazy import lazy_attributes

if TYPE_CHECKING:
    from tuners.classical.constrained import KNOBS, constrained_design
    from tuners.classical.rules import FOPDT, METHODS, design, fit_fopdt

__all__ = ["FOPDT", "KNOBS", "METHODS", "constrained_design", "design", "fit_fopdt"]

#: Imported on first use: ``python -m tuners.classical --help`` answers before the core loads.
_LAZY = {
    "KNOBS": "tuners.classical.constrained",
    "constrained_design": "tuners.classical.constrained",
    "FOPDT": "tuners.classical.rules",
    "METHODS": "tuners.classical.rules",
    "design": "tuners.classical.rules",
    "fit_fopdt": "tuners.classical.rules",
}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)

"""The textbook designs as a search's first trials (Optuna's ``enqueue_trial``).

A search that starts from random gains spends most of its budget finding the region a control
engineer starts from. Enqueued first, the textbook rules' designs
(:mod:`tuners.classical.rules`) give the sampler a feasible region from its first batch: every
rule with a robustness knob, at :data:`KNOB_POINTS` settings across the knob's textbook range,
designed on every plant of the task (a design for one identification is a candidate for the
others). Designs outside the search space are clipped into it; MIGO and pidtune settings that
no gains reach are skipped.
"""

from __future__ import annotations

import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import Plant
from tuners.classical.constrained import KNOBS
from tuners.classical.rules import design
from tuners.settings import ClassicalSettings, load_settings

__all__ = ["KNOB_POINTS", "RULES", "textbook_designs"]

#: Settings of each rule's knob, spread over its textbook range.
KNOB_POINTS = 5
#: The rules whose designs start a search (lambda is SIMC without its integral cut-off).
RULES = ("simc", "amigo-pi", "amigo-pid", "migo", "pidtune")


def textbook_designs(
    plants: tuple[Plant, ...], disturbance: Disturbance, n: float
) -> list[PIDGains]:
    """The textbook designs (every rule of :data:`RULES` at :data:`KNOB_POINTS` knob settings,
    on every plant), duplicates removed, in a fixed order."""
    settings = load_settings(ClassicalSettings)
    out: list[PIDGains] = []
    seen: set[tuple[float, ...]] = set()
    for plant in plants:
        for rule in RULES:
            knob = KNOBS[rule]
            for value in knob.grid(KNOB_POINTS):
                try:
                    gains, _ = design(
                        rule,
                        plant,
                        disturbance,
                        settings.model_copy(update={knob.name: float(value)}),
                        n,
                    )
                except ValueError:  # MIGO / pidtune: no gains reach this setting
                    continue  # fmt: skip
                key = tuple(np.round(gains.as_array(), 12))
                if key not in seen and np.all(np.isfinite(gains.as_array())):
                    seen.add(key)
                    out.append(gains)
    return out

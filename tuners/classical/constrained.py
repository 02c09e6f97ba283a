"""Textbook rules at their best: each rule's robustness knob set under the searches' constraints.

A textbook rule has one knob that trades speed for robustness (:data:`KNOBS`): SIMC's and the
lambda rule's closed-loop time constant ``tau_c`` (as a multiple of the dead time), the dead
time AMIGO is given (a multiple of the effective one), MIGO's ``Ms`` target and pidtune's
crossover frequency. Run at one fixed setting (``tau_c = theta``, say) a rule is weaker than
the textbook allows: the engineer who uses it picks the knob. :func:`constrained_design` does
what that engineer does, with the searches' own yardstick:

1. the rule's design for every knob value on a grid over the knob's textbook range;
2. every design is scored on the searches' tuning task (plants, tuning seeds) and judged by the
   searches' admission rule (:mod:`gripper_env.evaluation.admission`: ``Ms`` and gain margin
   with the servo's 20 ms hold on every plant, every run settled, no stall, the jaw inside the
   nearest stops the preset can draw); the feasible ones compete on their cost;
3. the best of them is refined twice by a finer scan between its neighbours (the cost is
   piecewise constant in some knobs and falls off a cliff at the constraints: no local
   minimiser would do).

The knob's value, the grid and the fixed-setting design are recorded; a knob that ends on the
edge of its range is flagged like a search result on a bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripper_env.evaluation.scoring import GainScorer
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import Plant
from tuners.classical.rules import design
from tuners.settings import ClassicalSettings

__all__ = ["KNOBS", "Knob", "constrained_design"]


@dataclass(frozen=True)
class Knob:
    """A rule's robustness knob: a field of :class:`~tuners.settings.ClassicalSettings` and its
    textbook range (searched log-uniformly when ``log``)."""

    name: str
    low: float
    high: float
    log: bool = True
    meaning: str = ""

    def grid(self, n: int) -> np.ndarray:
        if self.log:
            return np.geomspace(self.low, self.high, n)
        return np.linspace(self.low, self.high, n)

    def coordinate(self, value: float) -> float:
        """Position of ``value`` in [0, 1] over the range (log or linear)."""
        if self.log:
            return math.log(value / self.low) / math.log(self.high / self.low)
        return (value - self.low) / (self.high - self.low)


#: Each rule's robustness knob.
KNOBS: dict[str, Knob] = {
    "simc": Knob("tau_c_factor", 0.5, 8.0, meaning="tau_c / theta"),
    "lambda": Knob("tau_c_factor", 0.5, 8.0, meaning="lambda / theta"),
    "amigo-pi": Knob("theta_factor", 0.3, 8.0, meaning="assumed dead time / effective"),
    "amigo-pid": Knob("theta_factor", 0.3, 8.0, meaning="assumed dead time / effective"),
    "migo": Knob("migo_ms", 1.1, 2.5, log=False, meaning="Ms target"),
    "pidtune": Knob("pidtune_wc_hz", 0.2, 20.0, meaning="crossover frequency, Hz (PM 60 deg)"),
}

#: Grid points of the knob scan, then of each of its refinements.
GRID_POINTS = 25
REFINE_POINTS = 17
REFINEMENTS = 2
#: A knob within this fraction of its range's edge is flagged as on a bound.
BOUND_TOLERANCE = 0.02


def _design(
    method: str, plant: Plant, disturbance: Disturbance, settings: ClassicalSettings, n: float,
    value: float,
) -> PIDGains | None:  # fmt: skip
    knob = KNOBS[method]
    try:
        gains, _ = design(
            method, plant, disturbance, settings.model_copy(update={knob.name: value}), n
        )
    except ValueError:  # MIGO or pidtune: no gains reach the target at this setting
        return None
    return gains


def constrained_design(
    method: str,
    plant: Plant,
    disturbance: Disturbance,
    settings: ClassicalSettings,
    scorer: GainScorer,
    n: float = 100.0,
) -> tuple[PIDGains, dict[str, Any]]:
    """The rule ``method`` with its knob at the best setting that meets the constraints.

    Parameters
    ----------
    method : str
        A rule with a knob (:data:`KNOBS`).
    plant : Plant
        The plant the rule reads its model off.
    disturbance : Disturbance
        The actual-gripper preset (its loop: hold and delay).
    settings : ClassicalSettings
        The rules' settings (the knob's own value there is the fixed setting, recorded).
    scorer : GainScorer
        Scores gain sets on the tuning task (plants, tuning seeds) with the constraints.
    n : float
        Derivative filter coefficient (1/s).

    Returns
    -------
    gains : PIDGains
        The design at the chosen knob.
    tuning : dict
        The knob (name, value, range, on-bound flag), the grid's verdicts, the fixed-setting
        design and the episodes simulated.

    Raises
    ------
    ValueError
        No setting of the knob meets the constraints.
    """
    if method not in KNOBS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(KNOBS)}")
    knob = KNOBS[method]
    objective = scorer.task.objective
    lim = objective.constraints
    evaluated: dict[float, tuple[float, bool, PIDGains | None]] = {}
    refusals: dict[float, tuple[float, str | None, str | None]] = {}  # violation, binding, why

    def score(values: list[float]) -> None:
        designs = [(v, _design(method, plant, disturbance, settings, n, v)) for v in values]
        rows = [(v, g) for v, g in designs if g is not None]
        for v, g in designs:
            if g is None:
                evaluated[v] = (math.inf, False, None)
        if not rows:
            return
        s = scorer.score(np.stack([g.as_array() for _, g in rows]))
        penalised = objective.penalised(s.cost, np.where(s.feasible, 0.0, 1.0))
        for i, (v, g) in enumerate(rows):
            evaluated[v] = (float(penalised[i]), bool(s.feasible[i]), g)
            if not s.feasible[i]:
                refusals[v] = (float(s.violation[i]), s.admission.binding(i),
                               s.admission.reason(i, "binding"))  # fmt: skip

    grid = knob.grid(GRID_POINTS)
    score(list(grid))
    if not any(evaluated[v][1] for v in grid):
        nearest = min(refusals.values(), key=lambda r: r[0]) if refusals else None
        clearance = lim.limits(scorer.task.search)["stop_clearance_deg"]
        why = (f"; binding constraint '{nearest[1]}' at the nearest setting: {nearest[2]}"
               if nearest else "; no setting gives gains")  # fmt: skip
        raise ValueError(
            f"{method}: infeasible: no setting of {knob.name} in [{knob.low:g}, {knob.high:g}] "
            f"meets the admission rule (Ms <= {lim.ms_max:g}, GM >= {lim.gm_min_db:g} dB with "
            f"the hold, settled, no stall, {clearance:g} deg inside the nearest stops the preset "
            f"can draw){why}"
        )
    # refine twice between the best setting's neighbours: the cost is piecewise constant in
    # some knobs (pidtune's crossover snaps to a frequency grid) and falls off a cliff at the
    # constraints, so a finer scan, not a local minimiser
    for _ in range(REFINEMENTS):
        values = sorted(evaluated)
        best = min((v for v in values if evaluated[v][1]), key=lambda v: evaluated[v][0])
        i = values.index(best)
        lo, hi = values[max(i - 1, 0)], values[min(i + 1, len(values) - 1)]
        if knob.log:
            fine = np.geomspace(lo, hi, REFINE_POINTS)
        else:
            fine = np.linspace(lo, hi, REFINE_POINTS)
        score([float(v) for v in fine if float(v) not in evaluated])
    chosen = min((v for v, e in evaluated.items() if e[1]), key=lambda v: evaluated[v][0])
    gains = evaluated[chosen][2]
    assert gains is not None
    where = knob.coordinate(chosen)
    on_bound = []
    if where < BOUND_TOLERANCE or where > 1 - BOUND_TOLERANCE:
        edge = knob.low if where < 0.5 else knob.high
        on_bound.append(f"{knob.name} = {chosen:.4g} is at the edge {edge:g} of its range")
    fixed = _design(method, plant, disturbance, settings, n, getattr(settings, knob.name))
    _, notes = design(method, plant, disturbance,
                      settings.model_copy(update={knob.name: chosen}), n)  # fmt: skip
    return gains, {
        **notes,
        "knob": {
            "name": knob.name,
            "meaning": knob.meaning,
            "value": chosen,
            "range": [knob.low, knob.high],
            "scale": "log" if knob.log else "linear",
            "chosen_by": "least tuning cost among the settings that meet the admission rule",
        },
        "on_bound": on_bound,
        "best_value_tuning": evaluated[chosen][0],
        "feasible": True,
        "knob_scan": [
            {"value": float(v), "tuning_cost": (c if math.isfinite(c) else None), "feasible": f}
            for v, (c, f, _) in sorted(evaluated.items())
        ],
        "fixed_setting": {
            knob.name: getattr(settings, knob.name),
            "gains": None if fixed is None else [fixed.P, fixed.I, fixed.D, fixed.N],
        },
        "episodes": len(evaluated) * scorer.task.runs_per_gain_set,
    }

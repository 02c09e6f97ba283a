"""Where the searches look for gains: ranges scaled from the plant, and bound checks.

A fixed range (P up to 6, I up to 100) is too narrow for one plant and too wide for another: the
old searches put the integral gain on its bound of 100 on every plant. Here the ranges are
multiples of the plant's own scales, read off its first-order-plus-dead-time model on the loop
as it runs (:func:`tuners.classical.fit_fopdt`: gain ``k``, time constant ``tau``, effective dead
time ``theta`` including half the servo refresh):

* ``P`` in units of ``tau / (k theta)``: about the proportional gain at which the dead time eats
  the loop's phase (SIMC's tight PI has ``P = 0.5 tau / (k theta)``);
* ``I`` in units of ``1 / (k theta)`` (1/s): SIMC's tight PI has ``I ~ 0.5 / (k theta)`` for a
  lag-dominant plant;
* ``D`` in units of ``tau / k`` (s);
* ``N`` (1/s) is always absolute.

With several plants (the robust mode), P's and I's ranges are the tightest over the plants (one
gain set must stay robust on the most demanding plant: on test2-test4 together test4's P range
is a ninth of test2's, and the union of the ranges put nine tenths of the searched P where no
trial can be feasible), D's the widest. Every result is
checked against the bounds: a gain within 2 % of a bound, in the searched coordinate (linear,
log, or the magnitude of a symlog gain), is flagged, because the optimum may lie beyond it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from optuna.distributions import FloatDistribution

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import Plant
from tuners.fopdt import fit_fopdt
from tuners.settings import ClassicalSettings, OptunaSettings, ParamRange

__all__ = ["BOUND_TOLERANCE", "SearchSpace", "plant_scales", "search_space"]

#: A result this close to a bound (fraction of the searched coordinate's span) is flagged.
BOUND_TOLERANCE = 0.02


def plant_scales(plant: Plant, disturbance: Disturbance) -> dict[str, float]:
    """The plant's gain scales ``{"P": tau/(k theta), "I": 1/(k theta), "D": tau/k}``.

    Raises
    ------
    ValueError
        The plant has no FOPDT model (not open-loop stable): search it in absolute units.
    """
    try:
        m = fit_fopdt(plant, disturbance, ClassicalSettings())
    except ValueError as exc:
        raise ValueError(
            f"{exc}, and the search ranges in plant units come from that model; give absolute "
            "ranges ('units: absolute' under 'search' in --config)"
        ) from None
    k = abs(m.k)
    return {"P": m.tau_s / (k * m.theta_s), "I": 1.0 / (k * m.theta_s), "D": m.tau_s / k}


@dataclass(frozen=True)
class SearchSpace:
    """Absolute search ranges of the gains.

    Attributes
    ----------
    ranges : dict of str to ParamRange
        ``P``, ``I``, ``D`` (and ``N`` when it is searched), in gain units.
    tune_n : bool
        Whether ``N`` is searched.
    scales : dict of str to float
        The plant scales the ranges came from (empty for absolute ranges).
    """

    ranges: dict[str, ParamRange]
    tune_n: bool = False
    scales: dict[str, float] | None = None

    @property
    def names(self) -> list[str]:
        return ["P", "I", "D"] + (["N"] if self.tune_n else [])

    def distributions(self) -> dict[str, FloatDistribution]:
        """Optuna distributions (``symlog`` gains as floats in [-1, 1])."""

        def dist(r: ParamRange) -> FloatDistribution:
            if r.scale == "symlog":
                return FloatDistribution(-1.0, 1.0)
            return FloatDistribution(r.low, r.high, log=r.scale == "log")

        return {n: dist(self.ranges[n]) for n in self.names}

    def gains(self, params: dict[str, float], default_n: float) -> PIDGains:
        """Gains from a trial's searched parameters."""
        r = self.ranges
        n = r["N"].decode(params["N"]) if self.tune_n else default_n
        return PIDGains(
            r["P"].decode(params["P"]), r["I"].decode(params["I"]), r["D"].decode(params["D"]), n
        )

    def params(self, gains: PIDGains) -> dict[str, float]:
        """The searched parameters of ``gains`` (the inverse of :meth:`gains`), clipped into the
        ranges: what a warm start enqueues. A symlog gain below its smallest magnitude maps to
        that magnitude, with its sign (0 to the positive one)."""
        out = {}
        for name in self.names:
            r, v = self.ranges[name], float(getattr(gains, name))
            if r.scale == "symlog":
                mag = min(max(abs(v), r.low), r.high)
                u = math.log(mag / r.low) / math.log(r.high / r.low)
                out[name] = math.copysign(u, v) if v != 0 else 0.0
            else:
                out[name] = min(max(v, r.low), r.high)
        return out

    def position(self, gains: PIDGains) -> dict[str, float]:
        """Where each searched gain lies in its range, 0 to 1 in the searched coordinate (the
        magnitude's position for a symlog gain: 0 = smallest magnitude, 1 = largest)."""
        out = {}
        for name in self.names:
            r, v = self.ranges[name], getattr(gains, name)
            if r.scale == "linear":
                out[name] = (v - r.low) / (r.high - r.low)
            elif r.scale == "log":
                out[name] = math.log(v / r.low) / math.log(r.high / r.low) if v > 0 else 0.0
            else:
                mag = max(abs(v), r.low)
                out[name] = math.log(mag / r.low) / math.log(r.high / r.low)
        return out

    def on_bound(self, gains: PIDGains, tolerance: float = BOUND_TOLERANCE) -> list[str]:
        """Messages for the gains within ``tolerance`` of a search bound (the optimum may lie
        beyond). A symlog gain near its smallest magnitude is near zero, inside the range."""
        flags = []
        for name, pos in self.position(gains).items():
            r = self.ranges[name]
            value = getattr(gains, name)
            if pos >= 1.0 - tolerance:
                flags.append(f"{name} = {value:.4g} is at its upper search bound ({r.high:.4g})")
            elif pos <= tolerance and r.scale != "symlog":
                flags.append(f"{name} = {value:.4g} is at its lower search bound ({r.low:.4g})")
        return flags

    def as_dict(self) -> dict[str, Any]:
        """What the gains file records."""
        return {
            "ranges": {n: self.ranges[n].model_dump() for n in self.names},
            "plant_scales": self.scales or {},
        }


def search_space(
    plants: Sequence[Plant], disturbance: Disturbance, settings: OptunaSettings
) -> SearchSpace:
    """The absolute search ranges of ``settings.search`` for these plants (see the module
    docstring)."""
    s = settings.search
    if s.units == "absolute":
        ranges = {n: getattr(s, n) for n in ("P", "I", "D", "N")}
        return SearchSpace(ranges, settings.tune_N)
    scales = [plant_scales(p, disturbance) for p in plants]
    ranges = {"N": s.N}
    for name in ("P", "I", "D"):
        r = getattr(s, name)
        lows = [r.low * sc[name] for sc in scales]
        highs = [r.high * sc[name] for sc in scales]
        if name == "D":  # the widest: a lag (D < 0) that helps one plant may help them all
            ranges[name] = ParamRange(scale=r.scale, low=min(lows), high=max(highs))
        else:  # the tightest: one gain set must stay robust on the most demanding plant
            ranges[name] = ParamRange(scale=r.scale, low=max(lows), high=min(highs))
    widest = {name: max(sc[name] for sc in scales) for name in ("P", "I", "D")}
    return SearchSpace(ranges, settings.tune_N, widest)

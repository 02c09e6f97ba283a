"""Friction of the grey-box model: ``S`` and ``J`` as continuous parameters, and the values
consistent with the data.

Friction acts on the held servo command, upstream of the servo's linear dynamics, so for each
candidate ``(S, J)`` the core computes the position the servo is asked to follow (the *friction
output*), and the transfer function from it to the measured angle is refitted; the candidate's
cost is that fit's sum of squared errors. The friction output only changes on the servo's
refresh ticks, so the fits run on the tick grid (exact, 20x fewer samples), and the core runs two
steps per tick (:class:`gripper_env.sysid.core_batches.TickRuns`). Each refit
(:class:`TickCost`) is one Gauss-Newton step from a reference model: the numerator, the initial
state and the offset exactly, the poles and the delay linearised -- a least-squares problem.

1. :func:`coarse_friction`: a 1-degree grid over ``[0, max]^2`` finds the region;
2. :func:`locate_friction`: around it, at a given timing, lattices as fine as the servo's
   command (:func:`lattice_step`) follow the cost downhill; ``S - J`` (which moves the jaw
   continuously) is scanned finely across the best candidates; :func:`refine_friction` then
   moves the reference model to the best one and scores the lattice again;
3. :func:`friction_ranges`: the region ``V <= V_min + t sigma^2`` and the ends of its projections
   on ``S`` and ``J``, by bisection on the profile (the other parameter minimised), to
   :data:`EDGE_TOL_DEG`.

The cost is a step function of ``(S, J)``: a command quantised to ``q`` degrees makes the jaw
break free after a whole number of quanta of travel, so whole brackets of ``S`` and ``J`` give
the same friction output. A lattice coarser than ``q`` steps over brackets (with
``writeMicroseconds`` one bracket is 0.1 deg wide, and the next one's cost can be a thousand noise
variances higher), which is why its step follows the command. The minimum over many brackets
also chases the noise more than a smooth two-parameter fit would, so the chi-square threshold
(3.84) would make the region too small: ``t`` is the 95 % quantile of the likelihood ratio of the
estimate against the best candidate in data simulated from the estimate
(:func:`bootstrap_threshold`, a parametric bootstrap). With whole-degree commands
(``Servo.write``) ``S`` and ``J`` are known to their bracket: ``J = 0.3`` is reported as the
interval ``[0, 1)`` it shares with every ``J`` below one degree.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.sysid.core_batches import CoreRuns, TickRuns
from gripper_env.sysid.diagnostics import CHI2_95
from gripper_env.sysid.friction_cost import LinearFit, TickCost
from gripper_env.sysid.tfest import ESTIMATE, tfest

__all__ = [
    "EDGE_TOL_DEG",
    "FINE_STEP_DEG",
    "FrictionEstimate",
    "FrictionFit",
    "LinearFit",
    "TickCost",
    "bootstrap_threshold",
    "coarse_friction",
    "friction_ranges",
    "lattice_step",
    "locate_friction",
    "refine_friction",
    "scan_friction",
]

#: Largest step of the lattice (deg): whole-degree commands and coarser.
FINE_STEP_DEG = 0.25
#: Step of the lattice for unquantised commands (deg).
SMOOTH_STEP_DEG = 0.1
#: Resolution of the ends of the consistent ranges (deg).
EDGE_TOL_DEG = 0.02
#: Most rounds a lattice may follow the cost.
MAX_GROWTH = 40
#: Lattice candidates (the best) whose ``S - J`` is scanned finely.
OFFSET_SCANS = 3
#: Reach of the local lattice around the best candidate (deg).
LOCAL_RADIUS_DEG = 0.3
#: Bootstrap replicates of the likelihood-ratio threshold, and the candidates that take part:
#: those within this many noise variances of the best (farther ones never win a replicate).
BOOTSTRAP_REPLICATES = 200
BOOTSTRAP_MARGIN = 60.0


def lattice_step(quantum_deg: float) -> float:
    """Step of the friction lattice (deg) for commands quantised to ``quantum_deg`` (0: none):
    no coarser than the quantum, whose brackets it must not step over."""
    if quantum_deg <= 0:
        return SMOOTH_STEP_DEG
    if quantum_deg >= 4 * FINE_STEP_DEG:
        return FINE_STEP_DEG
    return float(quantum_deg) * 0.999  # a hair under, so that no bracket is skipped


@dataclass(frozen=True)
class FrictionEstimate:
    """Friction parameters and what the data can tell about them.

    Attributes
    ----------
    model : str
        ``"choudhury"`` or ``"kano"``.
    S_deg, J_deg : float
        The estimate (deg): the middle of the values consistent with the data (the best
        candidate when the middles are not jointly consistent).
    S_range_deg, J_range_deg : (float, float)
        The values consistent with the data: the 95 % interval (the projection of the
        likelihood-ratio region, its threshold calibrated by a parametric bootstrap), its ends
        located to :data:`EDGE_TOL_DEG`.
    best_S_deg, best_J_deg : float
        The candidate with the smallest cost (deg).
    max_deg : float
        Largest value considered (deg): an interval that reaches it is open upwards.
    grid_S_deg, grid_J_deg, grid_cost : ndarray
        The evaluated candidates and their costs (deg^2, fits on the tick grid).
    threshold : float
        The region's likelihood-ratio threshold, in noise variances (3.84 for one smooth
        parameter; more where the cost is a step function: :func:`bootstrap_threshold`).
    """

    model: str
    S_deg: float
    J_deg: float
    S_range_deg: tuple[float, float]
    J_range_deg: tuple[float, float]
    best_S_deg: float
    best_J_deg: float
    max_deg: float = math.inf
    grid_S_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    grid_J_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    grid_cost: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    threshold: float = CHI2_95

    def identified(self) -> dict[str, bool]:
        """Whether each interval is informative: within +/- 50 % of the estimate (or 0.5 deg
        wide), and not reaching the largest value considered."""
        out = {}
        for key, value, (lo, hi) in (
            ("S_deg", self.S_deg, self.S_range_deg),
            ("J_deg", self.J_deg, self.J_range_deg),
        ):
            out[key] = bool(hi - lo <= max(value, 0.5) and hi < self.max_deg - 1e-9)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "S_deg": self.S_deg,
            "J_deg": self.J_deg,
            "S_range_deg": list(self.S_range_deg),
            "J_range_deg": list(self.J_range_deg),
            "best_S_deg": self.best_S_deg,
            "best_J_deg": self.best_J_deg,
            "threshold": self.threshold,
            "identified": self.identified(),
        }


# ----------------------------------------------------------------------------------------------
# Coarse grid


def coarse_friction(
    core: CoreRuns, model: str, max_deg: float, n: int, m: int
) -> tuple[float, float]:
    """The best ``(S, J)`` of a 1-degree grid over ``[0, max_deg]^2`` (deg), refresh phase 0,
    scored from a transfer function (delay estimated) fitted at the grid's middle."""
    values = np.concatenate([[0.0], np.arange(0.5, max_deg, 1.0)])
    pairs = [(float(s), float(j)) for s in values for j in values]
    ticks = TickRuns(core, 0)
    y, dt = core.y[ticks.idx], core.dt * core.refresh
    middle = (float(values[len(values) // 2]), float(values[min(1, len(values) - 1)]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for pair in (middle, (0.0, 0.0)):
            v = ticks.friction_outputs([pair], model)[0]
            if np.ptp(v) > 0:
                est = tfest(dt, v, y, n, m, input_delay_s=ESTIMATE, max_delay_s=0.05,
                            check_feedback=False, nested_starts=False)  # fmt: skip
                break
        else:
            raise ValueError("the friction output never moves: the log does not excite the servo")
    cost = TickCost(ticks, y, dt, model, est.params, est.input_delay_s, n, m)
    costs = cost.linear(pairs)
    return pairs[int(np.argmin(costs))]


# ----------------------------------------------------------------------------------------------
# The minimum


def _snap(x: float) -> float:
    return round(float(x), 9)


@dataclass(frozen=True)
class FrictionFit:
    """Where the cost's minimum is (:func:`locate_friction`).

    Attributes
    ----------
    cost : TickCost
        The cost, from the best candidate's model.
    best : (float, float)
        The candidate ``(S, J)`` with the smallest cost (deg).
    candidates : list of (float, float)
        Every candidate scored.
    step_deg : float
        The lattice's step (deg).
    """

    cost: TickCost
    best: tuple[float, float]
    candidates: list[tuple[float, float]]
    step_deg: float

    @property
    def best_fit(self) -> LinearFit:
        return self.cost.fits[self.best]

    @property
    def sigma2(self) -> float:
        """Noise variance of the best fit (deg^2)."""
        return self.best_fit.cost / max(self.cost.n_ticks - self.cost.n_params, 1)


def _axis(step: float, max_deg: float) -> np.ndarray:
    return np.round(np.arange(0.0, max_deg + 1e-9, step), 9)


def _near(p: tuple[float, float], reach: int, axis: np.ndarray) -> list[tuple[float, float]]:
    i, j = (int(np.argmin(np.abs(axis - c))) for c in p)
    si = axis[max(0, i - reach) : i + reach + 1]
    sj = axis[max(0, j - reach) : j + reach + 1]
    return [(float(a), float(b)) for a in si for b in sj]


def _offset_scan(p: tuple[float, float], h: float, max_deg: float) -> list[tuple[float, float]]:
    """Candidates around ``p`` with ``S + J`` held and ``S - J`` changed by up to ``h`` either
    way in steps of ``h / 8``."""
    out = []
    for d in np.arange(-4, 5) * (h / 16.0):
        q = (_snap(p[0] + d), _snap(p[1] - d))
        if 0.0 <= q[0] <= max_deg and 0.0 <= q[1] <= max_deg:
            out.append(q)
    return out


def _downhill(
    cost: TickCost, start: tuple[float, float], step: float, radius: float, max_deg: float
) -> tuple[tuple[float, float], list[tuple[float, float]]]:
    """A lattice of ``step`` (deg), ``radius`` around the best candidate so far, scored until
    the best stops moving; returns the best and the lattice."""
    axis = _axis(step, max_deg)
    reach = max(1, math.ceil(radius / step))
    pairs = _near(start, reach, axis)
    have = set(pairs)
    best = start
    for _ in range(MAX_GROWTH):
        lin = cost.linear(pairs)
        best = pairs[int(np.argmin(lin))]
        new = [q for q in _near(best, reach, axis) if q not in have]
        if not new:
            break
        pairs += new
        have.update(new)
    return best, pairs


def locate_friction(
    cost: TickCost,
    start: tuple[float, float],
    max_deg: float,
    quantum_deg: float,
    radius_deg: float = LOCAL_RADIUS_DEG,
    scans: int = OFFSET_SCANS,
) -> FrictionFit:
    """The cost's minimum near ``start`` (found by :func:`scan_friction`): a lattice at the
    command's resolution following the cost downhill, ``radius_deg`` around the best, and a
    fine scan of ``S - J`` across the best ``scans``; ``max_deg`` bounds ``S`` and ``J`` (deg),
    ``quantum_deg`` is the command's resolution (deg; 0 for none)."""
    h = lattice_step(quantum_deg)
    _, pairs = _downhill(cost, start, h, radius_deg, max_deg)
    return _with_offsets(cost, pairs, h, max_deg, scans)


def _with_offsets(
    cost: TickCost,
    pairs: list[tuple[float, float]],
    h: float,
    max_deg: float,
    scans: int = OFFSET_SCANS,
) -> FrictionFit:
    """The candidates, a fine scan of ``S - J`` across the best ``scans``, and the best."""
    lin = cost.linear(pairs)
    for i in np.argsort(lin)[:scans]:
        pairs += _offset_scan(pairs[int(i)], h, max_deg)
    pairs = list(dict.fromkeys(pairs))
    lin = cost.linear(pairs)
    return FrictionFit(cost, pairs[int(np.argmin(lin))], pairs, h)


def scan_friction(
    cost: TickCost,
    start: tuple[float, float],
    max_deg: float,
    quantum_deg: float,
    stages: str = "both",
) -> tuple[float, float]:
    """A global search: whole lines of the lattice (every ``J`` at the best ``S``, then every
    ``S`` at the best ``J``) from ``start``, twice at :data:`FINE_STEP_DEG`, then once at the
    command's resolution. With commands quantised finer than the lattice the cost is a needle
    in a haystack along ``J`` (the number of quanta the jaw travels before it slips sets the
    whole staircase of a ramp): no local search finds it, a line does. ``stages``: ``"coarse"``
    or ``"fine"`` runs one of the two lattices only."""
    best = start
    steps = list(dict.fromkeys((FINE_STEP_DEG, lattice_step(quantum_deg))))
    if stages == "coarse":
        steps = steps[:1]
    elif stages == "fine":
        steps = steps[-1:]
    for step in steps:
        axis = _axis(step, max_deg)
        # twice on the first lattice (from a coarse start), once on a finer one (from its best)
        for _ in range(2 if step == steps[0] and stages != "fine" else 1):
            for k in (1, 0):
                line = [(best[0], float(a)) if k == 1 else (float(a), best[1]) for a in axis]
                line.append(best)
                best = line[int(np.argmin(cost.linear(line)))]
    return best


def refine_friction(
    fit: FrictionFit, max_deg: float, radius_deg: float = LOCAL_RADIUS_DEG
) -> FrictionFit:
    """:func:`locate_friction`'s result from the best candidate's model (a second Gauss-Newton
    step for every candidate), the lattice following the cost once more."""
    cost = fit.cost.recentred(fit.best_fit)
    _, lattice = _downhill(cost, fit.best, fit.step_deg, radius_deg, max_deg)
    pairs = list(dict.fromkeys(fit.candidates + lattice))
    # a fine square around the best: the best value can be a sliver where an S bracket, a J
    # bracket and the strip of S - J meet, between the lattice's points
    h = fit.step_deg
    lin = cost.linear(pairs)
    offsets = np.arange(-3, 4) * (h / 6.0)
    for i in np.argsort(lin)[:1]:
        s0, j0 = pairs[int(i)]
        pairs += [(_snap(s0 + a), _snap(j0 + b)) for a in offsets for b in offsets
                  if 0.0 <= s0 + a <= max_deg and 0.0 <= j0 + b <= max_deg]  # fmt: skip
    return _with_offsets(cost, list(dict.fromkeys(pairs)), h, max_deg)


# ----------------------------------------------------------------------------------------------
# The region and its projections


def bootstrap_threshold(
    fit: FrictionFit, seed: int = 0, replicates: int = BOOTSTRAP_REPLICATES
) -> float:
    """95 % quantile of the likelihood ratio ``(V(estimate) - min_c V(c)) / sigma^2`` over the
    scored candidates, in data simulated from the estimate (its fitted output plus Gaussian
    noise of the fit's variance): the region's threshold (at least 3.84)."""
    cost = fit.cost
    lin = cost.linear(fit.candidates)
    s2 = fit.sigma2
    near = [p for p, c in zip(fit.candidates, lin, strict=True)
            if c <= lin.min() + BOOTSTRAP_MARGIN * s2]  # fmt: skip
    if len(near) < 2:
        return CHI2_95
    q_best = cost.residual_matrix(fit.best)
    y_hat = q_best @ (q_best.T @ cost.y)  # the estimate's fitted output
    rng = np.random.default_rng(seed)
    ys = y_hat[:, None] + math.sqrt(s2) * rng.standard_normal((cost.n_ticks, replicates))
    total = np.einsum("ij,ij->j", ys, ys)

    def rss(q: np.ndarray) -> np.ndarray:
        proj = q.T @ ys
        return total - np.einsum("ij,ij->j", proj, proj)

    at_best = rss(q_best)
    lowest = at_best.copy()
    for p in near:
        if p != fit.best:
            lowest = np.minimum(lowest, rss(cost.residual_matrix(p)))
    ratio = (at_best - lowest) / s2
    return max(CHI2_95, float(np.quantile(ratio, 0.95)))


def friction_ranges(
    fit: FrictionFit,
    model: str,
    max_deg: float,
    threshold: float,
    say: Callable[[str], None] = lambda _m: None,
) -> FrictionEstimate:
    """The estimate and the 95 % intervals of ``S`` and ``J``: the projections of the region
    ``V <= V_min + threshold sigma^2``, their ends by bisection on the profile (the other
    parameter minimised), to :data:`EDGE_TOL_DEG`."""
    cost = fit.cost
    bound = fit.best_fit.cost + threshold * fit.sigma2
    lin = cost.linear(fit.candidates)
    ok = [p for p, c in zip(fit.candidates, lin, strict=True) if c <= bound]
    s_rng = _profile_ends(cost, ok, bound, 0, fit.step_deg, max_deg)
    j_rng = _profile_ends(cost, ok, bound, 1, fit.step_deg, max_deg)
    s_est, j_est = 0.5 * (s_rng[0] + s_rng[1]), 0.5 * (j_rng[0] + j_rng[1])
    if cost.linear([(_snap(s_est), _snap(j_est))])[0] > bound:  # not jointly consistent
        s_est, j_est = fit.best
    grid = np.array(list(cost.fits.keys()))
    say(
        f"friction, {len(cost.fits)} candidates: S {s_est:.3g} deg "
        f"[{s_rng[0]:.3g}, {s_rng[1]:.3g}], J {j_est:.3g} deg [{j_rng[0]:.3g}, {j_rng[1]:.3g}]"
    )
    return FrictionEstimate(
        model=model,
        S_deg=float(s_est),
        J_deg=float(j_est),
        S_range_deg=s_rng,
        J_range_deg=j_rng,
        best_S_deg=float(fit.best[0]),
        best_J_deg=float(fit.best[1]),
        max_deg=float(max_deg),
        grid_S_deg=grid[:, 0],
        grid_J_deg=grid[:, 1],
        grid_cost=np.array([f.cost for f in cost.fits.values()]),
        threshold=float(threshold),
    )


def consistent_fits(
    fit: FrictionFit, threshold: float
) -> list[tuple[tuple[float, float], LinearFit]]:
    """Every scored candidate ``(S, J)`` in the region ``V <= V_min + threshold sigma^2``, with
    its fit: the friction values the transfer function's and the delay's intervals must allow
    for."""
    bound = fit.best_fit.cost + threshold * fit.sigma2
    return [(p, f) for p, f in fit.cost.fits.items() if f.cost <= bound]


def _profile_ends(
    cost: TickCost,
    ok: list[tuple[float, float]],
    bound: float,
    k: int,
    h: float,
    max_deg: float,
) -> tuple[float, float]:
    """Ends of the projection of the region on coordinate ``k`` (0: S, 1: J).

    A value ``x`` is inside when some value of the other coordinate is: a scan of it (steps of
    ``h / 2``, then ``h / 16`` around the best two, since it moves ``S - J`` continuously) below
    the bound. From the outermost candidate inside, the interval is walked outward a lattice step
    at a time while it stays inside (the scan following the strip of ``S - J``), then the last
    step is bisected; the outside end of the last step is reported."""
    other = 1 - k
    lo = min(p[other] for p in ok)
    hi = max(p[other] for p in ok)

    def point(x: float, o: float) -> tuple[float, float]:
        return (_snap(x), _snap(o)) if k == 0 else (_snap(o), _snap(x))

    def inside(x: float, span: list[float]) -> bool:
        a, b = max(0.0, span[0] - 2 * h), min(max_deg, span[1] + 2 * h)
        pts = [point(x, o) for o in np.arange(a, b + 1e-9, 0.5 * h)]
        lin = cost.linear(pts)
        for i in np.argsort(lin)[:2]:
            o0 = pts[int(i)][other]
            pts += [point(x, o) for o in o0 + np.arange(-4, 5) * (h / 16.0) if 0 <= o <= max_deg]
        lin = cost.linear(pts)
        i = int(np.argmin(lin))
        if lin[i] <= bound:
            span[0], span[1] = min(span[0], pts[i][other]), max(span[1], pts[i][other])
            return True
        return False

    ends = []
    for sign in (-1.0, 1.0):
        span = [lo, hi]
        inner = (max if sign > 0 else min)(p[k] for p in ok)
        outer = inner + sign * h
        while 0.0 <= outer <= max_deg and inside(outer, span):
            inner, outer = outer, outer + sign * h
        if not 0.0 <= outer <= max_deg:
            ends.append(0.0 if sign < 0 else max_deg)
            continue
        while abs(outer - inner) > EDGE_TOL_DEG:
            mid = 0.5 * (inner + outer)
            if inside(mid, list(span)):
                inner = mid
            else:
                outer = mid
        ends.append(float(outer))
    return float(ends[0]), float(ends[1])

"""Friction of the grey-box model by profile likelihood: ``S`` and ``J`` as continuous
parameters, and the values consistent with the data.

Friction acts on the held servo command, upstream of the servo's linear dynamics, so for each
candidate ``(S, J)`` the core computes the position the servo is asked to follow (the *friction
output*), and the transfer function from it to the measured angle is refitted; the candidate's
cost is that fit's sum of squared errors. The friction output only changes on the servo's
refresh ticks, so the fits run on the tick grid (exact, 20x fewer samples), and the core runs two
steps per tick (:class:`gripper_env.sysid.core_batches.TickRuns`).

1. :func:`coarse_friction`: a 1-degree grid over ``[0, max]^2`` finds the region;
2. :func:`profile_friction`: around it, at a given timing, every candidate on a lattice as fine as
   the servo's command (:func:`lattice_step`) is scored with the transfer function's poles held
   (its numerator, initial state and offset refitted: a linear least-squares problem), the
   lattice following the cost downhill; the candidates near the best are then refitted with the
   poles free (output error) -- the profile likelihood proper -- and every candidate within the
   95 % likelihood-ratio bound (``V <= V_min (1 + 3.84 / (N - p))``) is consistent with the data;
   the consistent set grows until its neighbours are all outside, and its ends along ``S`` and
   ``J`` are located by bisection, to :data:`EDGE_TOL_DEG`.

The cost is a step function of ``(S, J)``: a command quantised to ``q`` degrees makes the jaw
break free after a whole number of quanta of travel, so whole brackets of ``S`` and ``J`` give
the same friction output. A lattice coarser than ``q`` steps over brackets (with
``writeMicroseconds`` one bracket is 0.1 deg wide, and the next one's cost can be a thousand noise
variances higher), which is why its step follows the command. With whole-degree commands
(``Servo.write``) ``S`` and ``J`` are known to their bracket: ``J = 0.3`` is reported as the
interval ``[0, 1)`` it shares with every ``J`` below one degree. ``S - J`` (the offset while
moving) acts continuously. The interval of each parameter is the projection of the consistent
set: its profile-likelihood interval.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.sysid.core_batches import CoreRuns, TickRuns
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.diagnostics import CHI2_95
from gripper_env.sysid.output_error import refine_output_error
from gripper_env.sysid.srivc import split_params
from gripper_env.sysid.tfest import ESTIMATE, tfest
from gripper_env.sysid.zoh import filtered_derivatives, zoh_response

__all__ = [
    "EDGE_TOL_DEG",
    "FINE_STEP_DEG",
    "FrictionEstimate",
    "TickCost",
    "coarse_friction",
    "lattice_step",
    "profile_friction",
]

#: Largest step of the lattice (deg): whole-degree commands and coarser.
FINE_STEP_DEG = 0.25
#: Step of the lattice for unquantised commands (deg).
SMOOTH_STEP_DEG = 0.1
#: Resolution of the ends of the consistent ranges (deg).
EDGE_TOL_DEG = 0.02
#: Output-error evaluations of each refit with the poles free (from the timing's model).
INNER_NFEV = 8
#: Candidates refitted with the poles free: those within this many noise variances of the best
#: with the poles held (holding them costs a little; far candidates cannot come back).
REFIT_MARGIN = 30.0
#: Most rounds the lattice and the consistent set may grow.
MAX_GROWTH = 40


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
        The values consistent with the data: the 95 % profile-likelihood interval, its ends
        located to :data:`EDGE_TOL_DEG`.
    best_S_deg, best_J_deg : float
        The candidate with the smallest cost (deg).
    max_deg : float
        Largest value considered (deg): an interval that reaches it is open upwards.
    grid_S_deg, grid_J_deg, grid_cost : ndarray
        The evaluated candidates and their costs (deg^2, fits on the tick grid).
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

    def identified(self) -> dict[str, bool]:
        """Whether each interval is informative: narrower than the larger of half the estimate
        and 0.5 deg, and not reaching the largest value considered."""
        out = {}
        for key, value, (lo, hi) in (
            ("S_deg", self.S_deg, self.S_range_deg),
            ("J_deg", self.J_deg, self.J_range_deg),
        ):
            out[key] = bool(hi - lo <= max(0.5 * value, 0.5) and hi < self.max_deg - 1e-9)
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
            "identified": self.identified(),
        }


# ----------------------------------------------------------------------------------------------
# The cost of a candidate


class TickCost:
    """Cost of friction candidates on one refresh phase's tick grid, at a fixed sensor delay:
    each candidate's friction output (core), and the transfer function refitted to it from a
    given model -- with its poles held (:meth:`linear`) or free (:meth:`__call__`)."""

    def __init__(
        self,
        core: CoreRuns,
        model: str,
        phase: int,
        delay_s: float,
        theta: np.ndarray,
        n: int,
        m: int,
    ) -> None:
        self.model, self.phase, self.delay_s = model, phase, delay_s
        self.theta, self.n, self.m = np.asarray(theta, dtype=float), n, m
        self.ticks = TickRuns(core, phase)
        self.y = core.y[self.ticks.idx]
        self.dt = core.dt * core.refresh
        self.cache: dict[tuple[float, float], float] = {}
        self.thetas: dict[tuple[float, float], np.ndarray] = {}
        self._outputs: dict[tuple[float, float], np.ndarray] = {}
        self._linear: dict[tuple[float, float], float] = {}
        self._by_output: dict[bytes, tuple[float, np.ndarray]] = {}
        _, den = split_params(self.theta, n)
        self._den = den
        zero = np.zeros(self.y.size)
        free = [zoh_response([1.0], den, zero, self.dt, x0=np.eye(n)[i]) for i in range(n)]
        self._free = np.column_stack([*free, np.ones(self.y.size)])

    @property
    def n_ticks(self) -> int:
        """Samples of the fits."""
        return int(self.y.size)

    @property
    def n_params(self) -> int:
        """Parameters of a refit: coefficients, initial state, output offset."""
        return self.n + self.m + 1 + self.n + 1

    def outputs(self, pairs: list[tuple[float, float]]) -> list[np.ndarray]:
        """Friction outputs (deg) at the ticks, computed once per candidate."""
        todo = list(dict.fromkeys(p for p in pairs if p not in self._outputs))
        if todo:
            for pair, v in zip(todo, self.ticks.friction_outputs(todo, self.model), strict=True):
                self._outputs[pair] = v
        return [self._outputs[p] for p in pairs]

    def linear(self, pairs: list[tuple[float, float]]) -> np.ndarray:
        """Costs (deg^2) with the poles held: numerator, initial state and offset refitted."""
        out = []
        for pair, v in zip(pairs, self.outputs(pairs), strict=True):
            if pair not in self._linear:
                self._linear[pair] = self._held_poles(v)
            out.append(self._linear[pair])
        return np.array(out)

    def _held_poles(self, v: np.ndarray) -> float:
        if np.ptp(v) == 0:
            return float(np.sum((self.y - self.y.mean()) ** 2))
        forced = filtered_derivatives(self._den, v - v[0], self.dt, "zoh", self.delay_s)
        basis = np.column_stack([forced[:, : self.m + 1], self._free])
        coef, *_ = np.linalg.lstsq(basis, self.y, rcond=None)
        r = self.y - basis @ coef
        return float(r @ r)

    def __call__(self, pairs: list[tuple[float, float]]) -> np.ndarray:
        """Costs (deg^2) with the poles free (output error from the given model)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for pair, v in zip(pairs, self.outputs(pairs), strict=True):
                if pair in self.cache:
                    continue
                key = v.tobytes()
                if key not in self._by_output:
                    self._by_output[key] = self._refit(v)
                self.cache[pair], self.thetas[pair] = self._by_output[key]
        return np.array([self.cache[p] for p in pairs])

    def _refit(self, v: np.ndarray) -> tuple[float, np.ndarray]:
        if np.ptp(v) == 0:
            return float(np.sum((self.y - self.y.mean()) ** 2)), self.theta
        data = prepare_data(self.dt, v, self.y, offset="initial")
        oe = refine_output_error(
            data, self.n, self.m, self.theta, delay_s=self.delay_s, max_nfev=INNER_NFEV,
            ftol=0.02 / data.n_samples,
        )  # fmt: skip
        return float(oe.residuals @ oe.residuals), oe.theta


# ----------------------------------------------------------------------------------------------
# Coarse grid


def coarse_friction(
    core: CoreRuns, model: str, max_deg: float, n: int, m: int
) -> tuple[float, float]:
    """The best ``(S, J)`` of a 1-degree grid over ``[0, max_deg]^2`` (deg), refresh phase 0,
    scored with the poles of a transfer function (delay estimated) fitted at the grid's
    middle."""
    values = np.concatenate([[0.0], np.arange(0.5, max_deg, 1.0)])
    pairs = [(float(s), float(j)) for s in values for j in values]
    ticks = TickRuns(core, 0)
    y, dt = core.y[ticks.idx], core.dt * core.refresh
    middle = (float(values[len(values) // 2]), float(values[min(1, len(values) - 1)]))
    theta, tau = np.zeros(n + m + 1), 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for pair in (middle, (0.0, 0.0)):
            v = ticks.friction_outputs([pair], model)[0]
            if np.ptp(v) > 0:
                est = tfest(dt, v, y, n, m, input_delay_s=ESTIMATE, max_delay_s=0.05,
                            check_feedback=False, nested_starts=False)  # fmt: skip
                theta, tau = est.params, est.input_delay_s
                break
        else:
            raise ValueError("the friction output never moves: the log does not excite the servo")
    cost = TickCost(core, model, 0, tau, theta, n, m)
    costs = cost.linear(pairs)
    return pairs[int(np.argmin(costs))]


# ----------------------------------------------------------------------------------------------
# The profile


def _snap(x: float) -> float:
    return round(float(x), 9)


def profile_friction(
    cost: TickCost,
    model: str,
    start: tuple[float, float],
    max_deg: float,
    quantum_deg: float,
    say: Callable[[str], None] = lambda _m: None,
) -> FrictionEstimate:
    """The friction estimate and its consistent ranges around ``start`` (see the module
    docstring); ``max_deg`` bounds ``S`` and ``J`` (deg), ``quantum_deg`` is the command's
    resolution (deg; 0 for none)."""
    h = lattice_step(quantum_deg)
    axis = np.round(np.arange(0.0, max_deg + 1e-9, h), 9)
    dof = max(cost.n_ticks - cost.n_params, 1)

    def near(p: tuple[float, float], reach: int) -> list[tuple[float, float]]:
        i, j = (int(np.argmin(np.abs(axis - c))) for c in p)
        si = axis[max(0, i - reach) : i + reach + 1]
        sj = axis[max(0, j - reach) : j + reach + 1]
        return [(float(a), float(b)) for a in si for b in sj]

    # 1. the lattice with the poles held, following the cost downhill
    reach = max(1, math.ceil(1.0 / h))  # a window of +/- 1 deg
    pairs = near(start, reach)
    for _ in range(MAX_GROWTH):
        lin = cost.linear(pairs)
        best = pairs[int(np.argmin(lin))]
        new = [q for q in near(best, reach) if q not in set(pairs)]
        if not new:
            break
        pairs += new
    lin = cost.linear(pairs)
    sigma2 = float(lin.min()) / dof
    close = [p for p, c in zip(pairs, lin, strict=True) if c <= lin.min() + REFIT_MARGIN * sigma2]
    # 2. the poles free near the best; the consistent set and its neighbours
    done: set[tuple[float, float]] = set()
    todo = close
    for _ in range(MAX_GROWTH):
        cost(todo)
        done.update(todo)
        pts = sorted(done)
        costs = cost(pts)
        bound = float(costs.min()) * (1.0 + CHI2_95 / dof)
        ok = [p for p, c in zip(pts, costs, strict=True) if c <= bound]
        todo = [q for p in ok for q in near(p, 1) if q not in done]
        todo = list(dict.fromkeys(todo))
        if not todo:
            break
    best = pts[int(np.argmin(costs))]
    s_rng = _edges(cost, ok, bound, 0, h, max_deg)
    j_rng = _edges(cost, ok, bound, 1, h, max_deg)
    s_est, j_est = 0.5 * (s_rng[0] + s_rng[1]), 0.5 * (j_rng[0] + j_rng[1])
    if cost([(_snap(s_est), _snap(j_est))])[0] > bound:  # the middles are not jointly consistent
        s_est, j_est = best
    grid = np.array(list(cost.cache.keys()))
    say(
        f"friction, {len(cost.cache)} refits: S {s_est:.3g} deg [{s_rng[0]:.3g}, {s_rng[1]:.3g}],"
        f" J {j_est:.3g} deg [{j_rng[0]:.3g}, {j_rng[1]:.3g}]"
    )
    return FrictionEstimate(
        model=model,
        S_deg=float(s_est),
        J_deg=float(j_est),
        S_range_deg=s_rng,
        J_range_deg=j_rng,
        best_S_deg=float(best[0]),
        best_J_deg=float(best[1]),
        max_deg=float(max_deg),
        grid_S_deg=grid[:, 0],
        grid_J_deg=grid[:, 1],
        grid_cost=np.array(list(cost.cache.values())),
    )


def _edges(
    cost: TickCost,
    ok: list[tuple[float, float]],
    bound: float,
    k: int,
    h: float,
    max_deg: float,
) -> tuple[float, float]:
    """Ends of the consistent set along coordinate ``k`` (0: S, 1: J): from the outermost
    consistent point, bisected toward its inconsistent neighbour along the axis and along both
    diagonals (the set is a strip along ``S - J``, which moves the jaw continuously); the
    farthest reach, to the inconsistent side of the last step."""
    ends = []
    for sign in (-1.0, 1.0):
        edge = max(ok, key=lambda p: p[k]) if sign > 0 else min(ok, key=lambda p: p[k])
        reach = edge[k]
        for slant in (0.0, 1.0, -1.0):
            step = np.zeros(2)
            step[k], step[1 - k] = sign * h, slant * h
            inner, outer = 0.0, 1.0

            def at(t: float, edge: tuple[float, float] = edge, step: np.ndarray = step):
                return _snap(edge[0] + t * step[0]), _snap(edge[1] + t * step[1])

            far = at(outer)
            if min(far) < 0.0 or max(far) > max_deg:
                if slant == 0.0:
                    reach = 0.0 if sign < 0 else max_deg
                continue
            while (outer - inner) * h > EDGE_TOL_DEG:
                mid = 0.5 * (inner + outer)
                if cost([at(mid)])[0] <= bound:
                    inner = mid
                else:
                    outer = mid
            x = at(outer)[k]
            reach = min(reach, x) if sign < 0 else max(reach, x)
        ends.append(float(reach))
    return float(ends[0]), float(ends[1])

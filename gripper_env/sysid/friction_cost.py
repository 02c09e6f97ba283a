"""The cost of a friction candidate for the grey-box fit (:mod:`gripper_env.sysid.
friction_profile`): the candidate's friction output on a refresh phase's tick grid, and the
transfer function refitted to it by one Gauss-Newton step from a reference model (numerator,
initial state and offset exactly; poles and delay linearised).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from gripper_env.model.state_space import controllable_form, discretise
from gripper_env.sysid.core_batches import CoreRuns, TickRuns
from gripper_env.sysid.srivc import split_params, stabilise
from gripper_env.sysid.zoh import delayed_input, run_states, zoh_response

__all__ = ["LinearFit", "TickCost"]


@dataclass(frozen=True)
class LinearFit:
    """A candidate's transfer function, one Gauss-Newton step from the reference model.

    Attributes
    ----------
    cost : float
        Sum of squared errors on the tick grid (deg^2).
    theta : ndarray
        ``[a_{n-1}..a_0, b_m..b_0]``.
    delay_s : float
        Sensor delay (s).
    unit_std : ndarray
        Standard errors of ``[theta, delay]`` per unit noise standard deviation
        (``sqrt(diag((X^T X)^-1))``).
    """

    cost: float
    theta: np.ndarray
    delay_s: float
    unit_std: np.ndarray


class TickCost:
    """Cost of friction candidates on one refresh phase's tick grid, from a reference transfer
    function and delay: each candidate's friction output (core), and the model refitted to it
    by one Gauss-Newton step (numerator, initial state and offset exact; poles and delay
    linearised). Without ``ticks`` it scores given friction outputs (:meth:`fit_output`), at
    any rate."""

    def __init__(
        self,
        ticks: TickRuns | None,
        y: np.ndarray,
        dt_s: float,
        model: str,
        theta: np.ndarray,
        delay_s: float,
        n: int,
        m: int,
    ) -> None:
        self.ticks, self.y, self.dt, self.model = ticks, y, dt_s, model
        self.theta, self.delay_s = np.asarray(theta, dtype=float), float(delay_s)
        self.n, self.m = n, m
        self.num, den = split_params(self.theta, n)
        # a reference with a pole in the right half plane (a step gone too far) is reflected
        self.den, _ = stabilise(den)
        self.theta = np.concatenate([self.den[1:], self.num])
        self._a_mat, self._b_vec = controllable_form(self.den)
        self._filters: dict[tuple[str, float], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        zero = np.zeros(y.size)
        free = [zoh_response([1.0], self.den, zero, dt_s, x0=np.eye(n)[i]) for i in range(n)]
        self._free = np.column_stack([*free, np.ones(y.size)])
        self.fits: dict[tuple[float, float], LinearFit] = {}
        self._by_output: dict[bytes, LinearFit] = {}

    @classmethod
    def at_phase(
        cls,
        core: CoreRuns,
        phase: int,
        model: str,
        theta: np.ndarray,
        delay_s: float,
        n: int,
        m: int,
    ) -> TickCost:
        """The cost on ``phase``'s ticks of the log in ``core``."""
        ticks = TickRuns(core, phase)
        return cls(ticks, core.y[ticks.idx], core.dt * core.refresh, model, theta, delay_s, n, m)

    def recentred(self, fit: LinearFit) -> TickCost:
        """The same candidates from another reference model (the friction outputs are kept)."""
        return TickCost(self.ticks, self.y, self.dt, self.model, fit.theta,
                        min(max(fit.delay_s, 0.0), 0.05), self.n, self.m)  # fmt: skip

    @property
    def n_ticks(self) -> int:
        """Samples of the fits."""
        return int(self.y.size)

    @property
    def n_params(self) -> int:
        """Parameters of a fit: coefficients, delay, initial state, output offset."""
        return self.n + self.m + 1 + 1 + self.n + 1

    def _filtered(self, w: np.ndarray, hold: str, frac: float = 0.0) -> np.ndarray:
        """``s^i / A w`` for ``i = 0 .. n`` (:func:`gripper_env.sysid.zoh.filtered_derivatives`
        with the reference's sampled filters computed once)."""
        key = (hold, frac)
        if key not in self._filters:
            self._filters[key] = discretise(self._a_mat, self._b_vec, self.dt, hold, frac)
        phi, g0, g1 = self._filters[key]
        states = run_states(phi, g0, g1, np.ascontiguousarray(w), np.zeros(self.n))
        top = w - states @ self.den[:0:-1]
        return np.column_stack([states, top])

    def basis(self, v: np.ndarray) -> np.ndarray:
        """Regressors of the step for the friction output ``v`` (ticks): the poles'
        sensitivities, the numerator's ``s^k / A v`` (delayed), the delay's sensitivity, the
        initial state's free responses and a constant."""
        n, m = self.n, self.m
        w, frac = delayed_input(v - v[0], self.delay_s, self.dt)
        forced = self._filtered(w, "zoh", frac)
        y0 = forced[:, : m + 1] @ self.num[::-1]
        x = np.empty((v.size, self.n_params))
        x[:, :n] = -self._filtered(y0, "foh")[:, n - 1 :: -1]
        x[:, n : n + m + 1] = forced[:, m::-1]
        # d/dtau of B/A v(t - tau) = -B s/A v: the next filtered derivatives (m < n)
        x[:, n + m + 1] = -(forced[:, 1 : m + 2] @ self.num[::-1]) if m < n else 0.0
        x[:, n + m + 2 :] = self._free
        return x

    def linear(self, pairs: list[tuple[float, float]]) -> np.ndarray:
        """Costs (deg^2) of ``pairs`` of ``(S, J)`` (deg), each computed once."""
        todo = list(dict.fromkeys(p for p in pairs if p not in self.fits))
        if todo:
            assert self.ticks is not None, "a TickCost without ticks scores outputs only"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for pair, v in zip(todo, self.ticks.friction_outputs(todo, self.model),
                                   strict=True):  # fmt: skip
                    key = v.tobytes()
                    if key not in self._by_output:
                        self._by_output[key] = self.fit_output(v)
                    self.fits[pair] = self._by_output[key]
        return np.array([self.fits[p].cost for p in pairs])

    def fit_output(self, v: np.ndarray) -> LinearFit:
        """The step's fit to the friction output ``v`` (deg, one value per sample of ``y``)."""
        k = self.n + self.m + 1
        if np.ptp(v) == 0:
            cost = float(np.sum((self.y - self.y.mean()) ** 2))
            return LinearFit(cost, self.theta, self.delay_s, np.full(k + 1, np.inf))
        with np.errstate(all="ignore"):
            x = self.basis(v)
        bad = LinearFit(math.inf, self.theta, self.delay_s, np.full(k + 1, np.inf))
        if not np.all(np.isfinite(x)):
            return bad
        # normal equations, columns scaled (a handful of regressors: a QR costs 5x more)
        gram = x.T @ x
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0] = 1.0
        try:
            inv = np.linalg.inv(gram / np.outer(scale, scale))
        except np.linalg.LinAlgError:
            return bad
        coef = (inv @ ((x.T @ self.y) / scale)) / scale
        resid = self.y - x @ coef
        theta = np.concatenate([self.theta[: self.n] + coef[: self.n], coef[self.n : k]])
        unit = np.sqrt(np.clip(np.diag(inv), 0.0, None))[: k + 1] / scale[: k + 1]
        return LinearFit(float(resid @ resid), theta, self.delay_s + float(coef[k]), unit)

    def residual_matrix(self, pair: tuple[float, float]) -> np.ndarray:
        """Orthonormal basis of the candidate's regressors (for :func:`bootstrap_threshold`)."""
        assert self.ticks is not None
        v = self.ticks.friction_outputs([pair], self.model)[0]
        with np.errstate(all="ignore"):
            x = self.basis(v) if np.ptp(v) > 0 else np.ones((v.size, 1))
        if not np.all(np.isfinite(x)):
            x = np.ones((v.size, 1))
        q, _ = np.linalg.qr(x)
        return q

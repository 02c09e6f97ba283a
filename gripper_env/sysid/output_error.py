"""Output-error refinement of a continuous-time transfer function (the step after SRIVC).

Minimises the simulation error ``sum_k (y_k - yhat_k)^2`` over the coefficients of
``B(s)/A(s)`` and the initial state, where ``yhat`` is the exact ZOH-sampled response of
``B/A`` to the held input plus the free response of the observer-form initial state ``x0``
(:func:`gripper_env.sysid.zoh.zoh_response`). The search is
:func:`scipy.optimize.least_squares` (trust-region reflective) with the exact Jacobian of
:mod:`gripper_env.sysid.sensitivity`.

With ``enforce_stability`` the denominator coefficients are bounded below by 0 (necessary for a
Hurwitz polynomial, and sufficient for n <= 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from gripper_env.sysid.data import IOData
from gripper_env.sysid.sensitivity import model_sensitivities
from gripper_env.sysid.srivc import split_params
from gripper_env.sysid.zoh import zoh_response

__all__ = ["OutputErrorResult", "fit_initial_state", "refine_output_error"]


def fit_initial_state(
    data: IOData, num: np.ndarray, den: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares initial state for a fixed model.

    Returns
    -------
    x0 : ndarray
        Observer-form initial state (deviation units).
    y_hat : ndarray
        Simulated output with that state (deviations, deg).
    """
    with np.errstate(all="ignore"):
        sens = model_sensitivities(num, den, data.u, data.dt_s, with_initial_state=True)
    basis = sens.d_x0
    assert basis is not None
    if not (np.all(np.isfinite(sens.y_hat)) and np.all(np.isfinite(basis))):
        return np.zeros(den.size - 1), sens.y_hat
    x0 = np.linalg.lstsq(basis, data.y - sens.y_hat, rcond=None)[0]
    return x0, sens.y_hat + basis @ x0


class _Problem:
    """Residuals and Jacobian of the output-error fit."""

    def __init__(self, data: IOData, n_poles: int, n_zeros: int, estimate_x0: bool) -> None:
        self.data = data
        self.n = n_poles
        self.m = n_zeros
        self.estimate_x0 = estimate_x0

    def _unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        n_theta = self.n + self.m + 1
        num, den = split_params(p[:n_theta], self.n)
        x0 = p[n_theta:] if self.estimate_x0 else None
        return num, den, x0

    def residuals(self, p: np.ndarray) -> np.ndarray:
        num, den, x0 = self._unpack(p)
        with np.errstate(all="ignore"):
            return zoh_response(num, den, self.data.u, self.data.dt_s, x0) - self.data.y

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        num, den, x0 = self._unpack(p)
        with np.errstate(all="ignore"):
            sens = model_sensitivities(
                num, den, self.data.u, self.data.dt_s, x0, with_initial_state=self.estimate_x0
            )
        cols = [sens.d_a, sens.d_b]
        if sens.d_x0 is not None:
            cols.append(sens.d_x0)
        return np.column_stack(cols)


@dataclass(frozen=True)
class OutputErrorResult:
    """Outcome of :func:`refine_output_error`.

    Attributes
    ----------
    theta : ndarray
        ``[a_{n-1}..a_0, b_m..b_0]``.
    x0 : ndarray
        Observer-form initial state (zeros if it was not estimated).
    residuals : ndarray
        ``y - yhat`` (deviations, deg).
    cov : ndarray
        Covariance of ``[theta, x0]`` (or of ``theta`` alone), ``sigma^2 (J^T J)^-1``.
    n_iter : int
        Jacobian evaluations (trust-region iterations).
    converged : bool
        ``least_squares`` met a tolerance.
    message : str
        ``least_squares``'s message.
    """

    theta: np.ndarray
    x0: np.ndarray
    residuals: np.ndarray
    cov: np.ndarray
    n_iter: int
    converged: bool
    message: str


def _covariance(jac: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    n_obs, n_par = jac.shape
    dof = max(n_obs - n_par, 1)
    sigma2 = float(residuals @ residuals) / dof
    scale = np.sqrt(np.einsum("ij,ij->j", jac, jac))
    scale[scale == 0] = 1.0
    _, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
    inv = np.where(sv > sv[0] * 1e-13, 1.0 / np.where(sv > 0, sv, 1.0) ** 2, np.inf)
    with np.errstate(invalid="ignore"):
        cov = (vt.T * inv) @ vt
    cov = np.where(np.isfinite(cov), cov, np.inf)
    return sigma2 * cov / np.outer(scale, scale)


def refine_output_error(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    theta0: np.ndarray,
    *,
    estimate_x0: bool = True,
    enforce_stability: bool = True,
    max_nfev: int = 200,
    tol: float = 1e-10,
) -> OutputErrorResult:
    """Minimise the simulation error starting from ``theta0``.

    Parameters
    ----------
    data : IOData
        Prepared record (deviations).
    n_poles, n_zeros : int
        Model order.
    theta0 : ndarray
        Start ``[a_{n-1}..a_0, b_m..b_0]`` (stable).
    estimate_x0 : bool
        Estimate the initial state (else it is zero).
    enforce_stability : bool
        Keep the denominator coefficients >= 0.
    max_nfev : int
        Most residual evaluations.
    tol : float
        ``ftol``, ``xtol`` and ``gtol`` of :func:`scipy.optimize.least_squares`.

    Returns
    -------
    OutputErrorResult
    """
    n, m = n_poles, n_zeros
    problem = _Problem(data, n, m, estimate_x0)
    theta0 = np.asarray(theta0, dtype=float).copy()
    if estimate_x0:
        num, den = split_params(theta0, n)
        x0, _ = fit_initial_state(data, num, den)
        p0 = np.concatenate([theta0, x0])
    else:
        p0 = theta0
    lower = np.full(p0.size, -np.inf)
    if enforce_stability:
        lower[:n] = 0.0
        p0[:n] = np.maximum(p0[:n], 1e-12 * max(1.0, float(np.max(np.abs(p0[:n])))))
    res = least_squares(
        problem.residuals,
        p0,
        jac=problem.jacobian,
        bounds=(lower, np.full(p0.size, np.inf)),
        method="trf",
        x_scale="jac",
        ftol=tol,
        xtol=tol,
        gtol=tol,
        max_nfev=max_nfev,
    )
    p = res.x
    theta = p[: n + m + 1]
    x0 = p[n + m + 1 :] if estimate_x0 else np.zeros(n)
    residuals = -res.fun
    return OutputErrorResult(
        theta=theta,
        x0=np.array(x0),
        residuals=residuals,
        cov=_covariance(res.jac, residuals),
        n_iter=int(res.njev or 0),
        converged=bool(res.status > 0),
        message=str(res.message),
    )

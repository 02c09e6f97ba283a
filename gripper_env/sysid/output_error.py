"""Output-error refinement of a continuous-time transfer function (the step after SRIVC).

Minimises the simulation error ``sum_k (y_k - yhat_k)^2`` over the coefficients of
``B(s)/A(s)``, the initial state and (optionally) a correction of the output operating point,
where ``yhat`` is the exact ZOH-sampled response of ``B/A`` to the held input plus the free
response of the observer-form initial state ``x0`` (:func:`gripper_env.sysid.zoh.zoh_response`)
plus the offset correction. Estimating the offset matters: an operating point taken from a short
rest period is off by ``noise / sqrt(samples)``, and that bias alone can exceed the standard
errors of the coefficients. The search is
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
from gripper_env.sysid.error_model import parameter_covariance
from gripper_env.sysid.sensitivity import model_sensitivities
from gripper_env.sysid.srivc import split_params
from gripper_env.sysid.zoh import zoh_response

__all__ = ["OutputErrorResult", "fit_initial_state", "refine_output_error"]


def fit_initial_state(
    data: IOData,
    num: np.ndarray,
    den: np.ndarray,
    *,
    with_offset: bool = False,
    delay_s: float = 0.0,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares initial state (and output-offset correction) for a fixed model with input
    delay ``delay_s`` (s).

    Returns
    -------
    x0 : ndarray
        Observer-form initial state (deviation units).
    offset : float
        Output-offset correction (deg; 0 unless ``with_offset``).
    y_hat : ndarray
        Simulated output with them (deviations, deg).
    """
    with np.errstate(all="ignore"):
        sens = model_sensitivities(
            num, den, data.u, data.dt_s, with_initial_state=True, delay_s=delay_s
        )
    basis = sens.d_x0
    assert basis is not None
    if not (np.all(np.isfinite(sens.y_hat)) and np.all(np.isfinite(basis))):
        return np.zeros(den.size - 1), 0.0, sens.y_hat
    if with_offset:
        basis = np.column_stack([basis, np.ones(data.n_samples)])
    coef = np.linalg.lstsq(basis, data.y - sens.y_hat, rcond=None)[0]
    offset = float(coef[-1]) if with_offset else 0.0
    return coef[: den.size - 1], offset, sens.y_hat + basis @ coef


class _Problem:
    """Residuals and Jacobian of the output-error fit.

    Parameter vector: ``[theta, x0 (if estimated), offset (if estimated), delay (if
    estimated)]``. The derivative with respect to the delay is a one-sided difference (the
    sampled response has kinks where the delay crosses a whole sample).
    """

    def __init__(
        self,
        data: IOData,
        n_poles: int,
        n_zeros: int,
        estimate_x0: bool,
        estimate_offset: bool,
        delay_s: float | None,
        u: np.ndarray,
        max_delay_s: float,
    ) -> None:
        self.data = data
        self.n = n_poles
        self.m = n_zeros
        self.estimate_x0 = estimate_x0
        self.estimate_offset = estimate_offset
        self.fixed_delay = delay_s
        self.u = u
        self.max_delay_s = max_delay_s
        self.step_s = 1e-3 * data.dt_s

    def _unpack(
        self, p: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float, float]:
        n_theta = self.n + self.m + 1
        num, den = split_params(p[:n_theta], self.n)
        k = n_theta
        x0 = None
        if self.estimate_x0:
            x0 = p[k : k + self.n]
            k += self.n
        offset = 0.0
        if self.estimate_offset:
            offset = float(p[k])
            k += 1
        delay = float(p[k]) if self.fixed_delay is None else self.fixed_delay
        return num, den, x0, offset, max(delay, 0.0)

    def residuals(self, p: np.ndarray) -> np.ndarray:
        num, den, x0, offset, delay = self._unpack(p)
        with np.errstate(all="ignore"):
            y_hat = zoh_response(num, den, self.u, self.data.dt_s, x0, delay)
            return y_hat + offset - self.data.y

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        num, den, x0, _, delay = self._unpack(p)
        with np.errstate(all="ignore"):
            sens = model_sensitivities(
                num,
                den,
                self.u,
                self.data.dt_s,
                x0,
                with_initial_state=self.estimate_x0,
                delay_s=delay,
            )
        cols = [sens.d_a, sens.d_b]
        if sens.d_x0 is not None:
            cols.append(sens.d_x0)
        if self.estimate_offset:
            cols.append(np.ones((self.data.n_samples, 1)))
        if self.fixed_delay is None:
            h = self.step_s if delay + self.step_s <= self.max_delay_s else -self.step_s
            with np.errstate(all="ignore"):
                y_h = zoh_response(num, den, self.u, self.data.dt_s, x0, delay + h)
            cols.append(((y_h - sens.y_hat) / h)[:, None])
        return np.column_stack(cols)


@dataclass(frozen=True)
class OutputErrorResult:
    """Outcome of :func:`refine_output_error`.

    Attributes
    ----------
    theta : ndarray
        ``[a_{n-1}..a_0, b_m..b_0]``.
    delay_s : float
        Input delay (s): the estimate, or the fixed value.
    x0 : ndarray
        Observer-form initial state (zeros if it was not estimated).
    offset : float
        Correction of the output operating point (deg; 0 if it was not estimated).
    residuals : ndarray
        ``y - yhat`` (deviations, deg).
    cov : ndarray
        Covariance of ``[theta, x0, offset, delay]`` (the estimated ones) under the error model
        of :mod:`gripper_env.sysid.error_model` (white noise, stamp jitter, the loss).
    n_iter : int
        Jacobian evaluations (trust-region iterations).
    converged : bool
        ``least_squares`` met a tolerance.
    message : str
        ``least_squares``'s message.
    """

    theta: np.ndarray
    delay_s: float
    x0: np.ndarray
    offset: float
    residuals: np.ndarray
    cov: np.ndarray
    n_iter: int
    converged: bool
    message: str


def refine_output_error(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    theta0: np.ndarray,
    *,
    estimate_x0: bool = True,
    estimate_offset: bool = True,
    enforce_stability: bool = True,
    delay_s: float = 0.0,
    estimate_delay: bool = False,
    max_delay_s: float = np.inf,
    max_nfev: int = 200,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    gtol: float = 1e-8,
    loss: str = "linear",
    f_scale: float = 1.0,
    stamp_std_s: float = 0.0,
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
    estimate_offset : bool
        Estimate a constant correction of the output operating point.
    enforce_stability : bool
        Keep the denominator coefficients >= 0.
    delay_s : float
        Input delay (s): fixed, or the start when ``estimate_delay``.
    estimate_delay : bool
        Estimate the delay too, within ``[0, max_delay_s]``.
    max_delay_s : float
        Upper bound of the estimated delay (s).
    max_nfev : int
        Most residual evaluations.
    ftol, xtol, gtol : float
        Tolerances of :func:`scipy.optimize.least_squares`.
    loss : {"linear", "soft_l1", "huber"}
        Loss of :func:`scipy.optimize.least_squares` (robust to outliers unless linear).
    f_scale : float
        Residual (deg) where a robust loss starts to flatten: about the noise's standard
        deviation.
    stamp_std_s : float
        Spread of the sampling instants about the time stamps (s), for the covariance.

    Returns
    -------
    OutputErrorResult
    """
    n, m = n_poles, n_zeros
    problem = _Problem(
        data,
        n,
        m,
        estimate_x0,
        estimate_offset,
        None if estimate_delay else float(delay_s),
        data.u,
        float(max_delay_s),
    )
    theta0 = np.asarray(theta0, dtype=float).copy()
    num, den = split_params(theta0, n)
    x0, offset, _ = fit_initial_state(data, num, den, with_offset=estimate_offset, delay_s=delay_s)
    p0 = np.concatenate(
        [
            theta0,
            x0 if estimate_x0 else [],
            [offset] if estimate_offset else [],
            [min(max(delay_s, 0.0), max_delay_s)] if estimate_delay else [],
        ]
    )
    lower = np.full(p0.size, -np.inf)
    upper = np.full(p0.size, np.inf)
    if enforce_stability:
        lower[:n] = 0.0
        p0[:n] = np.maximum(p0[:n], 1e-12 * max(1.0, float(np.max(np.abs(p0[:n])))))
    if estimate_delay:
        lower[-1], upper[-1] = 0.0, max_delay_s
    res = least_squares(
        problem.residuals,
        p0,
        jac=problem.jacobian,
        bounds=(lower, upper),
        method="trf",
        x_scale="jac",
        ftol=ftol,
        xtol=xtol,
        gtol=gtol,
        max_nfev=max_nfev,
        loss=loss,
        f_scale=f_scale,
    )
    p = res.x
    num, den, x0_fit, offset, delay = problem._unpack(p)
    residuals = -res.fun
    # with a robust loss, least_squares returns its reweighted Jacobian: take the plain one
    jac = res.jac if loss == "linear" else problem.jacobian(p)
    rate = None
    if stamp_std_s > 0:
        rate = np.gradient(res.fun + data.y, data.dt_s)
    return OutputErrorResult(
        theta=p[: n + m + 1].copy(),
        delay_s=delay,
        x0=np.zeros(n) if x0_fit is None else np.array(x0_fit),
        offset=offset,
        residuals=residuals,
        cov=parameter_covariance(
            jac, residuals, loss=loss, f_scale=f_scale, rate=rate, stamp_std_s=stamp_std_s
        ),
        n_iter=int(res.njev or 0),
        converged=bool(res.status > 0),
        message=str(res.message),
    )

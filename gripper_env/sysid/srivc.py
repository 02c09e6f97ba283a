"""Instrumental-variable start for continuous-time transfer-function estimation.

Model (output error, continuous time, ``p = d/dt``)::

    y(t_k) = B(p) / A(p) u(t) + e(t_k),   A = p^n + a_{n-1} p^{n-1} + ... + a_0,
                                          B = b_m p^m + ... + b_0

1. **SVF least squares** (:func:`svf_least_squares`): filter ``u`` and ``y`` with the state-variable
   filters ``p^i / (p + lambda)^n`` so that their derivatives exist, and solve the linear
   regression ``y_f^(n) = -a_{n-1} y_f^(n-1) - ... - a_0 y_f + b_m u_f^(m) + ... + b_0 u_f``.
   Biased by noise, but only a start. :func:`initial_estimate` chooses ``lambda`` from the data:
   the value on a logarithmic grid whose estimate simulates the record best.
2. **SRIVC** (:func:`srivc`, simplified refined instrumental variable for continuous-time models,
   Young and Garnier): replace the filter by ``1 / A_j(p)`` from the previous iterate and use as
   instruments the same filtered derivatives of the noise-free auxiliary model output
   ``x_j = B_j/A_j u``. Iterate until the parameters stop changing. At convergence this is the
   output-error estimate for white noise, and it does not depend on ``lambda``.

Sampling: ``u`` is a held command, so its filtered derivatives are exact under ZOH, and so are the
auxiliary output's (``p^i B_j / A_j^2 u``, from :mod:`gripper_env.sysid.sensitivity`); the measured
``y`` is smooth and goes through first-order-hold (linear interpolation) filters. All filters are
simulated in state space (:mod:`gripper_env.sysid.zoh`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gripper_env.sysid.data import IOData
from gripper_env.sysid.sensitivity import model_sensitivities
from gripper_env.sysid.zoh import filtered_derivatives, zoh_response

__all__ = [
    "SrivcResult",
    "initial_estimate",
    "offset_cost",
    "split_params",
    "srivc",
    "stabilise",
    "svf_candidates",
    "svf_least_squares",
]


def split_params(theta: np.ndarray, n_poles: int) -> tuple[np.ndarray, np.ndarray]:
    """``theta = [a_{n-1}..a_0, b_m..b_0]`` -> ``(num, den)`` with monic ``den``."""
    den = np.concatenate([[1.0], theta[:n_poles]])
    return np.asarray(theta[n_poles:], dtype=float), den


def stabilise(den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reflect right-half-plane poles into the left half plane.

    Returns the new monic denominator and its poles. A pole on the imaginary axis moves to
    ``-1e-9 * max(1, |p|)`` so that the filter ``1/A`` stays stable.
    """
    poles = np.roots(den)
    re = -np.abs(poles.real)
    re = np.where(re == 0.0, -1e-9 * np.maximum(1.0, np.abs(poles)), re)
    poles = re + 1j * poles.imag
    return np.real(np.poly(poles)), poles


def _col_norms(x: np.ndarray) -> np.ndarray:
    norms = np.sqrt(np.einsum("ij,ij->j", x, x))
    norms[norms == 0] = 1.0
    return norms


def _solve(zeta: np.ndarray, phi: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Solve ``sum zeta phi^T theta = sum zeta target`` with column scaling."""
    scale = _col_norms(phi)
    zscale = _col_norms(zeta)
    lhs = (zeta.T @ phi) / np.outer(zscale, scale)
    rhs = (zeta.T @ target) / zscale
    try:
        sol = np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        sol = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return sol / scale


def _regressors(
    data: IOData,
    den: np.ndarray,
    n: int,
    m: int,
    uf: np.ndarray | None = None,
    delay_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Regressors ``[-y_f^(n-1) .. -y_f, u_f^(m) .. u_f, c_f^(n) .. c_f]`` and target
    ``y_f^(n)``; the input filters see ``u`` ``delay_s`` late.

    The last ``n + 1`` columns are the filtered derivatives of a constant: an output offset
    ``c`` (the operating point taken from a short rest, or a mean) enters the filtered equation
    as ``c A(p)/F(p) 1``, linear in ``c a_i``. With them the estimate does not depend on how the
    operating point was removed; their coefficients are dropped.
    """
    yf = filtered_derivatives(den, data.y, data.dt_s, "foh")
    if uf is None:
        uf = filtered_derivatives(den, data.u, data.dt_s, "zoh", delay_s)[:, : m + 1]
    cf = filtered_derivatives(den, np.ones(data.n_samples), data.dt_s, "foh")
    phi = np.column_stack([-yf[:, n - 1 :: -1], uf[:, ::-1], cf])
    return phi, yf[:, n]


def svf_least_squares(
    data: IOData, n_poles: int, n_zeros: int, lam_rad_s: float, delay_s: float = 0.0
) -> np.ndarray:
    """Least-squares fit through the state-variable filter ``1/(s + lambda)^n``.

    Parameters
    ----------
    data : IOData
        Prepared record (deviations).
    n_poles, n_zeros : int
        Model order.
    lam_rad_s : float
        Filter pole ``lambda`` (rad/s); about the bandwidth of the system works best.
    delay_s : float
        Input delay of the model (s).

    Returns
    -------
    ndarray
        ``theta = [a_{n-1}..a_0, b_m..b_0]``.
    """
    den = np.real(np.poly(np.full(n_poles, -float(lam_rad_s))))
    phi, target = _regressors(data, den, n_poles, n_zeros, delay_s=delay_s)
    return _solve(phi, phi, target)[: n_poles + n_zeros + 1]


def svf_candidates(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    lam_rad_s: float | None = None,
    delay_s: float = 0.0,
) -> list[tuple[float, np.ndarray, float]]:
    """SVF least-squares starts over a grid of filter poles, best first.

    The grid runs from the record's fundamental ``2 pi / T`` to a tenth of the Nyquist frequency,
    three points per decade (or is the one ``lam_rad_s`` given); each candidate is stabilised and
    simulated, and scored by its simulation error with the best constant output offset (so
    that how the operating point was removed does not decide the start).

    Returns
    -------
    list of (cost, theta, lam_rad_s)
        Sorted by cost (deg^2); ``theta = [a_{n-1}..a_0, b_m..b_0]``, stabilised.
    """
    if lam_rad_s is not None:
        if not np.isfinite(lam_rad_s) or lam_rad_s <= 0:
            raise ValueError(f"svf_lambda_rad_s must be positive, got {lam_rad_s}")
        grid = np.array([float(lam_rad_s)])
    else:
        t_rec = data.dt_s * data.n_samples
        lo, hi = 2 * np.pi / t_rec, 0.1 * np.pi / data.dt_s
        grid = np.logspace(np.log10(lo), np.log10(hi), max(2, int(3 * np.log10(hi / lo)) + 1))
    out = []
    for lam in grid:
        theta = svf_least_squares(data, n_poles, n_zeros, lam, delay_s)
        if not np.all(np.isfinite(theta)):
            continue
        num, den = split_params(theta, n_poles)
        den, _ = stabilise(den)
        cost = offset_cost(data.y, zoh_response(num, den, data.u, data.dt_s, delay_s=delay_s))
        if np.isfinite(cost):
            out.append((cost, np.concatenate([den[1:], num]), float(lam)))
    if not out:
        raise ValueError("the state-variable-filter start failed for every filter bandwidth")
    return sorted(out, key=lambda c: c[0])


def offset_cost(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Sum of squared errors after the best constant offset (deg^2)."""
    r = y - y_hat
    return float(r @ r - r.sum() ** 2 / r.size)


def initial_estimate(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    lam_rad_s: float | None = None,
    delay_s: float = 0.0,
) -> tuple[np.ndarray, float]:
    """The best SVF least-squares start (:func:`svf_candidates`).

    Returns
    -------
    theta : ndarray
        ``[a_{n-1}..a_0, b_m..b_0]`` (stabilised).
    lam_rad_s : float
        The filter pole used (rad/s).
    """
    _, theta, lam = svf_candidates(data, n_poles, n_zeros, lam_rad_s, delay_s)[0]
    return theta, lam


@dataclass(frozen=True)
class SrivcResult:
    """Outcome of :func:`srivc`.

    Attributes
    ----------
    theta : ndarray
        Best iterate (smallest simulation error), ``[a_{n-1}..a_0, b_m..b_0]``.
    n_iter : int
        Iterations run.
    converged : bool
        Whether the relative parameter change fell below the tolerance.
    cost : float
        Sum of squared simulation errors of ``theta`` from rest, after the best constant
        offset (deg^2).
    """

    theta: np.ndarray
    n_iter: int
    converged: bool
    cost: float


def srivc(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    theta0: np.ndarray,
    *,
    max_iter: int = 30,
    tol: float = 1e-7,
    max_stall: int = 3,
    delay_s: float = 0.0,
) -> SrivcResult:
    """Refine ``theta0`` with the SRIVC iterations (Young and Garnier).

    Parameters
    ----------
    data : IOData
        Prepared record (deviations).
    n_poles, n_zeros : int
        Model order.
    theta0 : ndarray
        Start, ``[a_{n-1}..a_0, b_m..b_0]``.
    max_iter : int
        Most iterations.
    tol : float
        Stop when ``||theta_{j+1} - theta_j|| <= tol * ||theta_j||`` (converged).
    max_stall : int
        Also stop after this many iterations in a row without a smaller simulation error
        (not converged; the best iterate is returned).
    delay_s : float
        Input delay of the model (s).
    Returns
    -------
    SrivcResult
    """
    n, m = n_poles, n_zeros
    theta = np.asarray(theta0, dtype=float)
    best = (np.inf, theta)
    converged = False
    it = 0
    stalled = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is reported)
        num, den = split_params(theta, n)
        den, _ = stabilise(den)
        theta = np.concatenate([den[1:], num])
        # Auxiliary model output x = B/A u, its filtered derivatives p^i/A x and p^k/A u.
        sens = model_sensitivities(num, den, data.u, data.dt_s, delay_s=delay_s)
        cost = offset_cost(data.y, sens.y_hat)
        if cost < best[0] * (1 - 1e-9):
            best = (cost, theta)
            stalled = 0
        else:
            stalled += 1
            if stalled >= max_stall:
                # With few independent samples of the slow noise (records a few time constants
                # long) the iterates wander instead of converging; the output-error step that
                # follows does not need more.
                break
        # d_a = -[p^{n-1}/A x, ..., x/A]: exactly the noise-free regressors; d_b = [p^m/A u ..].
        phi, target = _regressors(data, den, n, m, uf=sens.d_b[:, ::-1], delay_s=delay_s)
        # the constant's columns are their own instruments
        zeta = np.column_stack([sens.d_a, sens.d_b, phi[:, n + m + 1 :]])
        new = _solve(zeta, phi, target)[: n + m + 1]
        if not np.all(np.isfinite(new)):
            break
        step = float(np.linalg.norm(new - theta)) / max(float(np.linalg.norm(theta)), 1e-300)
        theta = new
        if step <= tol:
            converged = True
            break
    num, den = split_params(theta, n)
    den, _ = stabilise(den)
    cost = offset_cost(data.y, zoh_response(num, den, data.u, data.dt_s, delay_s=delay_s))
    if cost <= best[0]:
        best = (cost, np.concatenate([den[1:], num]))
    return SrivcResult(theta=best[1], n_iter=it, converged=converged, cost=best[0])
